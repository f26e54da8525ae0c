"""`make mutate`'s table (data_tools/mutations.toml) against the code as it is: each pattern once
in its file, so that a refactor that moves the code fails here, not in a mutation run hours
later, and every module's tests exist."""

from pathlib import Path

import pytest

from data_tools.mutate import check_table
from data_tools.mutations import MODULES, load

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", sorted(MODULES))
def test_each_mutation_is_in_its_file_once_and_its_tests_exist(name):
    module = MODULES[name]
    check_table(list(module.mutations))  # raises SystemExit naming the pattern
    assert not any(argument.startswith("@") for argument in module.tests)
    for argument in module.tests:
        if argument.startswith("tests/"):
            assert (ROOT / argument.split("::")[0]).is_file(), argument
    names = [m.name for m in module.mutations]
    assert len(names) == len(set(names)), "two mutations of one name"
    for m in module.mutations:
        assert m.pattern != m.replacement, m.name
        assert m.equivalent is None or m.equivalent.strip(), m.name


def test_the_table_names_its_test_lists_and_refuses_an_unknown_one(tmp_path):
    table = tmp_path / "mutations.toml"
    table.write_text(
        '[tests]\nfast = ["-m", "not slow"]\nmine = ["tests/a.py", "@fast"]\n'
        '[[module]]\nname = "m"\npath = "p.py"\ntests = ["@mine", "-x"]\n'
        '[[module.mutation]]\nname = "n"\npattern = """\na\n"""\nreplacement = "b"\n'
    )
    (module,) = load(table).values()
    assert module.tests == ("tests/a.py", "-m", "not slow", "-x")
    assert module.mutations[0].pattern == "a\n"  # the first line break is TOML's, not the pattern's
    table.write_text('[[module]]\nname = "m"\npath = "p.py"\ntests = ["@nothing"]\n')
    with pytest.raises(ValueError, match="nothing"):
        load(table)
