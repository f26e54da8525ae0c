"""Reading a Rerun recording back with Rerun's own reader: its rows by entity, and its blueprint
as views with their queries and properties (what the tests can see without a viewer)."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa
import rerun.chunk as rerun_chunk

# What each kind of view draws: a view shows an entity that carries one of these.
VIEW_COMPONENTS = {
    "3D": (
        "Points3D:positions",
        "LineStrips3D:strips",
        "Ellipsoids3D:half_sizes",
        "Transform3D:translation",
    ),
    "2D": (
        "EncodedImage:blob",
        "Boxes2D:half_sizes",
        "LineStrips2D:strips",
        "Points2D:positions",
    ),
    "TimeSeries": ("Scalars:scalars",),
    "TextLog": ("TextLog:text",),
    "TextDocument": ("TextDocument:text",),
}


def read_rows(path: Path) -> dict[str, list[dict]]:
    """Every row of the recording by entity, in log order within each pose (statics first)."""
    rows: dict[str, list[dict]] = defaultdict(list)
    for chunk in rerun_chunk.RrdReader(path).stream():
        columns = chunk.to_record_batch().to_pydict()
        for k in range(chunk.num_rows):
            rows[chunk.entity_path].append({name: values[k] for name, values in columns.items()})
    for entity_rows in rows.values():
        entity_rows.sort(key=lambda r: (r.get("pose", -1), r["rerun.controls.RowId"]))
    return rows


def data_rows(rows: list[dict], component: str) -> list[dict]:
    """The rows of an entity that carry `component`, clears left out."""
    return [r for r in rows if r.get(component) is not None]


def latest(rows: list[dict], component: str):
    """What a latest-at query at the end of the run gives: the last value, unless cleared."""
    value = None
    for r in rows:
        if r.get("Clear:is_recursive") is not None:
            value = None
        if r.get(component) is not None:
            value = r[component]
    return value


def plain(values: pa.Array) -> list:
    """An Arrow column of blueprint values as Python, unions named: a time range's boundary
    reads ("CursorRelative", -100), ("Absolute", 0) or ("Infinite", None) (`to_pylist` drops
    the kind, and pyarrow's union scalars misreport it for a variant without a value)."""
    kind = values.type
    valid = [v.is_valid for v in values]
    if pa.types.is_union(kind):
        children = [plain(values.field(i)) for i in range(kind.num_fields)]
        codes = values.type_codes.to_pylist()
        offsets = values.offsets.to_pylist()
        out = []
        for code, offset in zip(codes, offsets, strict=True):
            i = kind.type_codes.index(code)
            value = children[i][offset] if not pa.types.is_null(kind.field(i).type) else None
            out.append((kind.field(i).name, value))
        return out
    if pa.types.is_struct(kind):
        fields = {f.name: plain(values.field(f.name)) for f in kind}
        return [
            {name: column[k] for name, column in fields.items()} if ok else None
            for k, ok in enumerate(valid)
        ]
    if pa.types.is_list(kind) or pa.types.is_large_list(kind):
        flat = plain(values.values)
        offsets = values.offsets.to_pylist()
        return [flat[offsets[k] : offsets[k + 1]] if ok else None for k, ok in enumerate(valid)]
    return values.to_pylist()


@dataclass
class View:
    kind: str  # Rerun's class identifier: "3D", "2D", "TimeSeries", ...
    origin: str
    name: str
    id: str = ""
    query: list[str] = field(default_factory=list)
    # Properties by archetype ("EyeControls3D", "TextLogColumns", ...; overrides by their
    # path under the view, "ViewContents/overrides/world/uncertainty/visualizers"): a row of
    # component -> value.
    properties: dict[str, dict] = field(default_factory=dict)

    def shows(self, entity: str) -> bool:
        """Whether the view's query takes `entity` in (`+ PATH`, `+ PATH/**`, `- ...`; the
        last matching expression decides, as in Rerun)."""
        taken = False
        for expression in self.query:
            sign, _, path = expression.strip().rpartition(" ")
            path = path.replace("$origin", self.origin.rstrip("/"))
            if path.endswith("/**"):
                root = path[:-3] or "/"
                match = entity == root or entity.startswith(root.rstrip("/") + "/")
            else:
                match = entity == path
            if match:
                taken = sign != "-"
        return taken


def blueprint(path: Path) -> list[View]:
    """The views of the recording's blueprint, in no particular order."""
    reader = rerun_chunk.RrdReader(path)
    (store,) = reader.blueprints()
    views: dict[str, View] = {}
    properties: dict[str, dict[str, dict]] = defaultdict(dict)
    queries: dict[str, list[str]] = {}
    for chunk in reader.stream(store=store):
        parts = chunk.entity_path.strip("/").split("/")
        if parts[0] != "view":
            continue
        batch = chunk.to_record_batch()
        row = {name: plain(batch.column(name))[0] for name in batch.schema.names}
        view_id = parts[1]
        if len(parts) == 2:
            views[view_id] = View(
                kind=row["ViewBlueprint:class_identifier"][0],
                origin=row["ViewBlueprint:space_origin"][0],
                name=row["ViewBlueprint:display_name"][0],
                id=view_id,
            )
        elif parts[2:] == ["ViewContents"]:
            queries[view_id] = list(row["ViewContents:query"])
        else:
            properties[view_id]["/".join(parts[2:])] = row
    for view_id, view in views.items():
        view.query = queries.get(view_id, ["$origin/**"])
        view.properties = properties[view_id]
    return list(views.values())


def eye_coordinates(view: View, points) -> tuple:
    """Where `points` (N, 3) fall in a 3-D view's default eye: (across, up) over depth, to
    compare with tan(fov / 2) (times the aspect across), and the depth."""
    import numpy as np

    eye = view.properties["EyeControls3D"]
    position = np.array(eye["EyeControls3D:position"][0])
    target = np.array(eye["EyeControls3D:look_target"][0])
    up_hint = np.array(eye["EyeControls3D:eye_up"][0])
    forward = (target - position) / np.linalg.norm(target - position)
    right = np.cross(forward, up_hint)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    v = np.asarray(points, dtype=float) - position
    depth = v @ forward
    return v @ right / depth, v @ up / depth, depth


def containers(path: Path) -> list[list[str]]:
    """Each container of the blueprint: the ids of what it holds, in its order."""
    reader = rerun_chunk.RrdReader(path)
    (store,) = reader.blueprints()
    out = []
    for chunk in reader.stream(store=store):
        if chunk.entity_path.startswith("/container/"):
            batch = chunk.to_record_batch()
            if "ContainerBlueprint:contents" in batch.schema.names:
                contents = batch.column("ContainerBlueprint:contents").to_pylist()[0]
                out.append([c.split("/", 1)[1] for c in contents])
    return out


def blueprint_views(path: Path) -> list[tuple[str, str]]:
    return [(view.kind, view.origin) for view in blueprint(path)]


def unfed_views(path: Path) -> list[str]:
    """Views that draw nothing of the recording, and entities a view names one by one that
    carry nothing it draws: as "view name" or "view name: entity"."""
    rows = read_rows(path)

    def feeds(name: str, kind: str) -> bool:
        return any(data_rows(rows.get(name, []), c) for c in VIEW_COMPONENTS[kind])

    out = []
    for view in blueprint(path):
        if not any(view.shows(name) and feeds(name, view.kind) for name in rows):
            out.append(view.name)
        for expression in view.query:
            named = expression.strip().removeprefix("+ ")
            if "*" not in named and "$" not in named and not feeds(named, view.kind):
                out.append(f"{view.name}: {named}")
    return out


def unseen_entities(path: Path) -> list[str]:
    """Entities holding something a view could draw that no view of the blueprint takes in."""
    views = blueprint(path)
    drawn = {c for components in VIEW_COMPONENTS.values() for c in components}
    out = []
    for name, entity_rows in read_rows(path).items():
        if any(data_rows(entity_rows, c) for c in drawn) and not any(v.shows(name) for v in views):
            out.append(name)
    return out
