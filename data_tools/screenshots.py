"""Screenshots of Rerun recordings, taken without a screen: a virtual X display (Xvfb), the
Rerun viewer on Mesa's software Vulkan, and the viewer's own control server
(`rerun viewer-mcp`, JSON-RPC over its stdin) to move the time cursor, maximise a view and
save the picture. No clicking at guessed pixels: the viewer is told what to show by name.

Needs the Debian packages `xvfb mesa-vulkan-drivers libvulkan1` (and `libgl1-mesa-dri
libegl1`); CI has none of them, and nothing in the test suite runs this.

    python -m data_tools.screenshots RECORDING.rrd --pose 1500 --out shot.png [--view Map]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger("mmslam.screenshots")

WINDOW = (1600, 1000)
START_TIMEOUT_S = 60.0
LOAD_TIMEOUT_S = 300.0
# Frames the viewer renders after a change before the picture is taken (it draws lazily).
SETTLE_FRAMES = 10
# Times a call is made again when the viewer, busy, did not answer in time.
BUSY_RETRIES = 20
# Where the pointer waits while pictures are taken: the empty top bar (a pointer over a view
# shows a tooltip).
POINTER_PARK = {"x": 1100.0, "y": 16.0}


class ScreenshotError(RuntimeError):
    pass


def required_programs() -> list[str]:
    """The programs this needs that are missing (none, or the names to install)."""
    return [name for name in ("Xvfb",) if shutil.which(name) is None]


def viewer_binary() -> Path:
    """The Rerun viewer itself (the `rerun` script only starts it as a child process, which a
    signal to the script would leave running)."""
    import rerun_cli

    binary = Path(rerun_cli.__file__).parent / "rerun"
    if not binary.exists():
        raise ScreenshotError(f"no Rerun viewer at {binary}")
    return binary


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(process: subprocess.Popen) -> None:
    """Stop a process this module started in its own session, with its children."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


@contextmanager
def virtual_display(size: tuple[int, int] = WINDOW) -> Iterator[str]:
    """An X display of this size for as long as the block runs: its name (":N")."""
    number = next(n for n in range(90, 200) if not Path(f"/tmp/.X11-unix/X{n}").exists())
    name = f":{number}"
    # No Composite: with it the software renderer's window stays black.
    process = subprocess.Popen(
        ["Xvfb", name, "-screen", "0", f"{size[0]}x{size[1]}x24", "-nolisten", "tcp",
         "-extension", "Composite"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while not Path(f"/tmp/.X11-unix/X{number}").exists():
            if process.poll() is not None or time.monotonic() > deadline:
                raise ScreenshotError(f"Xvfb {name} did not start")
            time.sleep(0.1)
        yield name
    finally:
        _stop(process)


class ViewerControl:
    """The viewer's control server, spoken to over JSON-RPC (the Model Context Protocol)."""

    def __init__(self, port: int):
        self.process = subprocess.Popen(
            [str(viewer_binary()), "viewer-mcp", "--endpoint", f"http://127.0.0.1:{port}"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            start_new_session=True,
        )
        self._id = 0
        self._request("initialize", {
            "protocolVersion": "2024-11-05",
            "capabilities": {},
            "clientInfo": {"name": "mmslam-screenshots", "version": "1"},
        })  # fmt: skip
        self._send({"jsonrpc": "2.0", "method": "notifications/initialized"})

    def _send(self, message: dict) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write(json.dumps(message) + "\n")
        self.process.stdin.flush()

    def _request(self, method: str, params: dict) -> dict:
        self._id += 1
        self._send({"jsonrpc": "2.0", "id": self._id, "method": method, "params": params})
        assert self.process.stdout is not None
        while True:
            line = self.process.stdout.readline()
            if not line:
                raise ScreenshotError("the viewer's control server stopped")
            reply = json.loads(line)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise ScreenshotError(f"{method}: {reply['error']}")
                return reply["result"]

    def tool(self, name: str, **arguments) -> str:
        """Call one of the server's tools; its answer (the first text: the viewer's own log
        lines since the last call may follow it). A viewer busy loading a large recording may
        not answer in time: asked again, a few times."""
        for attempt in range(BUSY_RETRIES + 1):
            result = self._request("tools/call", {"name": name, "arguments": arguments})
            texts = [
                c.get("text", "") for c in result.get("content", []) if c.get("type") == "text"
            ]
            if not result.get("isError"):
                return texts[0] if texts else ""
            message = " ".join(texts)
            if "did not answer in time" not in message or attempt == BUSY_RETRIES:
                raise ScreenshotError(f"{name}: {message}")
            log.info("%s: the viewer is busy; asking again", name)
        raise AssertionError("unreachable")

    def state(self) -> dict:
        answer = self.tool("rerun_get_state")
        state, _ = json.JSONDecoder().raw_decode(answer)  # log lines may follow the object
        return state

    def close(self) -> None:
        _stop(self.process)


@contextmanager
def viewer(recording: Path, display: str, size: tuple[int, int] = WINDOW) -> Iterator[Viewer]:
    """The Rerun viewer showing `recording` on `display`, ready to be told what to show."""
    port = _free_port()
    runtime = tempfile.mkdtemp(prefix="mmslam-viewer-")
    environment = dict(os.environ, DISPLAY=display, WGPU_BACKEND="vulkan",
                       XDG_RUNTIME_DIR=runtime)  # fmt: skip
    process = subprocess.Popen(
        [str(viewer_binary()), "--port", str(port), "--renderer", "vulkan",
         "--window-size", f"{size[0]}x{size[1]}", str(recording)],
        env=environment,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )  # fmt: skip
    control = None
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:  # the control server dials the viewer's port, so wait for it
            try:
                socket.create_connection(("127.0.0.1", port), 1.0).close()
                break
            except OSError:
                if process.poll() is not None or time.monotonic() > deadline:
                    raise ScreenshotError("the Rerun viewer did not start") from None
                time.sleep(0.2)
        control = ViewerControl(port)
        yield Viewer(control)
    finally:
        if control is not None:
            control.close()
        _stop(process)
        shutil.rmtree(runtime, ignore_errors=True)


class Viewer:
    """What a screenshot needs of the viewer: wait for the recording, go to a pose, maximise a
    view, take the picture."""

    def __init__(self, control: ViewerControl):
        self.control = control

    def wait_loaded(self, timeline: str, last: int) -> None:
        """Until the recording's `timeline` reaches `last` (the whole file is in)."""
        deadline = time.monotonic() + LOAD_TIMEOUT_S
        while time.monotonic() < deadline:
            for recording in self.control.state().get("recordings", []):
                for t in recording.get("timelines", []):
                    end = t.get("time_range", {}).get("end")
                    if t["timeline"]["name"] == timeline and end is not None and end >= last:
                        return
            time.sleep(0.5)
        raise ScreenshotError(f"the recording did not reach {timeline} {last}")

    def settle(self) -> None:
        self.control.tool("wait_for", min_steps=SETTLE_FRAMES, timeout_secs=60)

    def go_to(self, timeline: str, time_value: int) -> None:
        self.control.tool(
            "rerun_set_time_cursor",
            timeline={"name": timeline},
            time={"time": time_value},
            play_state="PLAY_STATE_PAUSED",
        )

    def view_id(self, name: str) -> str:
        views = self.control.state().get("views", [])
        found = [v["view_id"] for v in views if v["name"] == name]
        if len(found) != 1:
            raise ScreenshotError(
                f"{len(found)} views named {name!r}: {[v['name'] for v in views]}"
            )
        return found[0]

    def maximise(self, name: str | None) -> None:
        """Show only the view `name`, as its maximise button does (None: the whole layout)."""
        view = self.view_id(name) if name is not None else None
        patch = {"/viewport": {"ViewportBlueprint": {"maximized": view}}}
        self.control.tool(
            "rerun_set_blueprint", recording={}, mode="partial", json=json.dumps(patch)
        )

    def save(self, path: Path) -> None:
        self.control.tool("hover", pos=POINTER_PARK)
        self.settle()
        path.parent.mkdir(parents=True, exist_ok=True)
        self.control.tool("rerun_save_screenshot", file_path=str(path.resolve()), max_size=0)
        if not path.exists():
            raise ScreenshotError(f"the viewer wrote no {path}")


@dataclass(frozen=True)
class Shot:
    """A picture of a recording at a pose of the `pose` timeline, the whole layout or one view
    maximised."""

    out: Path
    pose: int
    maximised: str | None = None


def take(recording: Path, shots: list[Shot], size: tuple[int, int] = WINDOW) -> None:
    """Every shot of one recording, in one viewer."""
    missing = required_programs()
    if missing:
        raise ScreenshotError(
            f"missing {', '.join(missing)}: apt-get install xvfb mesa-vulkan-drivers"
        )
    with virtual_display(size) as display, viewer(recording, display, size) as shown:
        shown.wait_loaded("pose", max(s.pose for s in shots))
        for shot in shots:
            shown.maximise(shot.maximised)
            shown.go_to("pose", shot.pose)
            shown.save(shot.out)
            log.info("wrote %s (%s at pose %d)", shot.out, recording.name, shot.pose)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("--pose", type=int, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--maximise", metavar="VIEW", help="show only this view (by its name)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    take(args.recording, [Shot(args.out, args.pose, args.maximise)])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
