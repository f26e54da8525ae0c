"""`make mutate`'s table (data_tools/mutations.py) against the code as it is: each pattern once
in its file, so that a refactor that moves the code fails here, not in a mutation run hours
later, and every module's tests exist."""

from pathlib import Path

import pytest

from data_tools.mutate import check_table
from data_tools.mutations import MODULES

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", sorted(MODULES))
def test_each_mutation_is_in_its_file_once_and_its_tests_exist(name):
    module = MODULES[name]
    check_table(list(module.mutations))  # raises SystemExit naming the pattern
    for argument in module.tests:
        if argument.startswith("tests/"):
            assert (ROOT / argument.split("::")[0]).is_file(), argument
