"""Where a Rerun recording goes: a file (written under a temporary name and renamed into place
only when the run finished), a new viewer, or a running one. Shared by a run's sink and by a
comparison of runs."""

from __future__ import annotations

import logging
import os
import shutil
import socket
import sys
import uuid
import weakref
from pathlib import Path
from urllib.parse import urlparse

import rerun as rr

from pipeline.errors import InputError
from pipeline.outputs import atomic_output

logger = logging.getLogger(__name__)

DEFAULT_PORT = 9876
VIEWER_WAIT_S = 2.0


def viewer_url(address: str) -> str:
    """A gRPC URL from `--connect`: a URL as Rerun takes it, `HOST:PORT`, or a bare port."""
    address = address.strip()
    if address.isdigit():
        address = f"127.0.0.1:{address}"
    if "://" not in address:
        address = f"rerun+http://{address}/proxy"
    parsed = urlparse(address)
    if parsed.scheme not in ("rerun", "rerun+http", "rerun+https") or not parsed.hostname:
        raise InputError(f"--connect {address}: expected HOST:PORT or rerun+http://HOST:PORT/proxy")
    try:
        parsed.port  # noqa: B018 - raises on a port that is not a number
    except ValueError:
        raise InputError(f"--connect {address}: the port is not a number") from None
    return address


def _listening(url: str, timeout_s: float) -> bool:
    parsed = urlparse(url)
    default = 443 if parsed.scheme == "rerun+https" else DEFAULT_PORT
    try:
        with socket.create_connection((parsed.hostname, parsed.port or default), timeout_s):
            return True
    except OSError:
        return False


def rerun_executable() -> str | None:
    """The viewer of this environment, found even when its bin/ is not on PATH."""
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.exists() else shutil.which("rerun")


def _discard(path: Path) -> None:
    path.unlink(missing_ok=True)


class Destination:
    """A recording stream and where it goes. `start` begins writing (a file), `close` flushes
    and, for a file, renames it into place if the run finished or deletes it if not."""

    def __init__(
        self,
        recording: rr.RecordingStream,
        *,
        target: Path | None = None,
        temporary: Path | None = None,
    ):
        self.rec = recording
        self.target = target
        self.temporary = temporary
        # A run that fails before `close` (or never reaches it) leaves no temporary behind.
        self._discard_at_exit = (
            weakref.finalize(self, _discard, temporary) if temporary is not None else None
        )
        self._closed = False

    @classmethod
    def open(
        cls,
        application: str,
        *,
        rrd: str | Path | None = None,
        spawn: bool = False,
        connect: str | None = None,
    ) -> Destination:
        """Exactly one of: a recording file, a new viewer, a running viewer."""
        if (rrd is not None) + bool(spawn) + (connect is not None) != 1:
            raise InputError("choose one of --rrd FILE, --spawn, --connect ADDR")
        # Rerun's own switch: a stream it disables would write an empty file (and say so at
        # exit). Read as Rerun reads it.
        if os.environ.get("RERUN", "").strip().lower() in ("0", "false", "off", "no"):
            raise InputError("Rerun is turned off by the environment variable RERUN: unset it")
        recording = rr.RecordingStream(application, recording_id=uuid.uuid4())
        # The log's own stamps make the `log_time` timeline; no wall-clock time, no ticks.
        recording.set_log_time_enabled(False)
        recording.set_log_tick_enabled(False)
        if rrd is not None:
            target = Path(rrd)
            if target.is_dir():
                raise InputError(f"--rrd {target}: is a directory")
            try:
                fd, temporary = atomic_output(target)
            except OSError as exc:
                raise InputError(f"--rrd {target}: cannot be written ({exc.strerror})") from None
            os.close(fd)
            return cls(recording, target=target, temporary=temporary)
        if spawn:
            url = f"rerun+http://127.0.0.1:{DEFAULT_PORT}/proxy"
            if not _listening(url, VIEWER_WAIT_S):  # else a viewer is there already: use it
                executable = rerun_executable()
                if executable is None:
                    raise InputError("--spawn: no `rerun` viewer executable found")
                rr.spawn(port=DEFAULT_PORT, connect=False, executable_path=executable)
                if not _listening(url, VIEWER_WAIT_S):
                    raise InputError(
                        "--spawn: the Rerun viewer did not start (no display?); "
                        "use --rrd FILE, or --connect to a viewer elsewhere"
                    )
            recording.connect_grpc(url)
            return cls(recording)
        url = viewer_url(connect or "")
        # Without a viewer Rerun buffers and retries, and every log call slows to a crawl.
        if not _listening(url, VIEWER_WAIT_S):
            raise InputError(f"--connect {connect}: no Rerun viewer listening at {url}")
        recording.connect_grpc(url)
        return cls(recording)

    def start(self) -> None:
        """Begin writing the file, if the destination is one."""
        if self.temporary is not None:
            self.rec.save(self.temporary)

    def close(self, finished: bool) -> None:
        """Flush and disconnect; a recording file is renamed into place only if `finished`, so
        a failed run leaves an earlier recording as it was."""
        if self._closed:
            return
        self._closed = True
        try:
            self.rec.flush()
            self.rec.disconnect()
        except RuntimeError as exc:  # a viewer that went away: nothing more to send
            logger.warning("rerun: %s", exc)
        if self.temporary is None or self.target is None:
            return
        if finished:
            os.replace(self.temporary, self.target)
            logger.info("wrote recording %s", self.target)
        else:
            self.temporary.unlink(missing_ok=True)
            logger.info("the run did not finish: no recording written to %s", self.target)
        if self._discard_at_exit is not None:
            self._discard_at_exit.detach()
