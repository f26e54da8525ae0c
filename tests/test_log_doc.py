"""The log's messages are declared once (pipeline/log/messages.py): the JSON Schemas in a log's
channels and docs/log-format.md's field tables are made from the declarations."""

from __future__ import annotations

import json

import msgspec
from mcap.reader import make_reader

from pipeline.log import doc, schemas
from tests.synthetic import small_square_log


def test_the_pages_field_tables_are_made_from_the_declarations():
    text = doc.PAGE.read_text()
    assert doc.page_with_tables(text) == text, "run: python -m pipeline.log.doc"
    assert doc.main(["--check"]) == 0


def test_the_tables_name_every_field_with_its_bounds():
    tables = doc.tables()
    assert "| `range` | number | m | in [0.001, 10000] |" in tables
    assert "| `bbox` (optional) | [4 numbers] | px | each in [-1e6, 1e6]; u_min <= u_max" in tables
    assert "| `class_id` | integer |  | in [0, 999]; below the log's num_classes |" in tables
    for _, cls in schemas.MESSAGES.values():
        for name in cls.__dataclass_fields__:
            assert f"| `{name}`" in tables


def test_a_logs_channels_carry_the_schemas_of_the_declarations(tmp_path):
    path = small_square_log(tmp_path / "log.mcap")
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    written = {
        s.name: json.loads(s.data) for s in summary.schemas.values() if s.encoding == "jsonschema"
    }
    for name, cls in schemas.MESSAGES.values():
        if name in written:
            assert written[name] == msgspec.json.schema(cls)
    assert {"mmslam.Odometry", "mmslam.Detections"} <= set(written)
    range_schema = written["mmslam.Detections"]["$defs"]["Detection"]["properties"]["range"]
    assert (range_schema["minimum"], range_schema["maximum"]) == (0.001, 10000.0)
