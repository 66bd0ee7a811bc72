"""Where the Rerun view goes: the ``--rerun`` option and opening the recording stream.

``--rerun spawn|connect[=ADDR]|save=PATH|serve[=ADDR:PORT]|off``. Parsing
touches neither the network nor a display, and Rerun is imported only in
:func:`open_recording`. The default is a viewer where there is a display and
an ``.rrd`` file next to the recording where there is none: spawning a viewer
without a display blocks for seconds and then drops the data.
"""

from __future__ import annotations

import ipaddress
import os
import socket
import sys
import uuid
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, Literal, TextIO
from urllib.parse import urlsplit

from ptinertia.errors import UsageError

DEFAULT_PORT = 9876
SERVER_MEMORY_LIMIT = "512MiB"
RERUN_HELP = (
    "where the live view goes: spawn (a local viewer), connect[=HOST:PORT|URL] (a running "
    "viewer), save=PATH (.rrd file), serve[=ADDR:PORT] (gRPC server, 127.0.0.1 unless an "
    "address is given), off. Default: spawn where there is a display, else save an .rrd "
    "next to the recording"
)
_URL_SCHEMES = ("rerun://", "rerun+http://", "rerun+https://")

Kind = Literal["spawn", "connect", "save", "serve", "off"]


@dataclass(frozen=True)
class ViewerMode:
    """Where the view goes.

    Attributes
    ----------
    kind : ``spawn``, ``connect``, ``save``, ``serve`` or ``off``.
    path : the ``.rrd`` file (``save``).
    url : the viewer's gRPC URL (``connect``).
    bind_ip, port : the server's address (``serve``); ``port`` is also the spawned viewer's.
    memory_limit : what the server keeps for viewers that connect late (``serve``).
    defaulted : chosen by the default rule rather than by the user.
    """

    kind: Kind
    path: Path | None = None
    url: str | None = None
    bind_ip: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    memory_limit: str = SERVER_MEMORY_LIMIT
    defaulted: bool = False

    @property
    def server_url(self) -> str:
        """The URL a viewer opens to reach a ``serve`` server."""
        host = self.bind_ip
        if host in ("0.0.0.0", "::"):
            host = socket.gethostname()
        elif ":" in host:
            host = f"[{host}]"
        return f"rerun+http://{host}:{self.port}/proxy"

    def open_hint(self) -> str | None:
        """How the user opens what this mode produces (None where a viewer already shows it)."""
        if self.kind == "save" and self.path is not None:
            return f"Rerun view saved to {self.path}; open it with: rerun {self.path}"
        if self.kind == "serve":
            return f"Rerun view served at {self.server_url}; open it with: rerun {self.server_url}"
        return None


def has_display(env: Mapping[str, str] | None = None, platform: str | None = None) -> bool:
    """Whether a viewer window can open: always on macOS/Windows, X11 or Wayland elsewhere."""
    env = os.environ if env is None else env
    platform = sys.platform if platform is None else platform
    if platform in ("darwin", "win32"):
        return True
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def default_rrd_path(recording_path: str | Path | None, now: datetime | None = None) -> Path:
    """``RECORDING.rrd`` beside the recording, else ``./ptinertia-YYYYmmdd-HHMMSS.rrd``."""
    if recording_path is not None:
        return Path(recording_path).with_suffix(".rrd")
    stamp = (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    return Path.cwd() / f"ptinertia-{stamp}.rrd"


def _split_host_port(text: str, what: str) -> tuple[str | None, int | None]:
    """``HOST``, ``HOST:PORT``, ``:PORT``, ``PORT``, ``[V6]:PORT`` -> (host or None, port or None)."""
    host: str | None
    port_text: str | None = None
    if text.isdigit():
        host, port_text = None, text
    elif text.startswith("["):
        close = text.find("]")
        if close < 0 or (close + 1 < len(text) and text[close + 1] != ":"):
            raise UsageError(f"--rerun {what}={text}: expected [IPv6]:PORT")
        host = text[1:close]
        port_text = text[close + 2 :] or None
    elif text.count(":") == 1:
        host, port_text = text.split(":")
        host = host or None
    else:  # a bare host, or an IPv6 address without a port
        host = text or None
    port = None
    if port_text is not None:
        if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
            raise UsageError(f"--rerun {what}={text}: port must be 1-65535, got {port_text!r}")
        port = int(port_text)
    return host, port


def _connect_url(arg: str) -> str:
    if arg.startswith(_URL_SCHEMES):
        return arg
    if "://" in arg:
        raise UsageError(
            f"--rerun connect={arg}: URL scheme must be one of {', '.join(_URL_SCHEMES)}"
        )
    host, port = _split_host_port(arg, "connect")
    host = host or "127.0.0.1"
    host = f"[{host}]" if ":" in host else host
    return f"rerun+http://{host}:{port or DEFAULT_PORT}/proxy"


def _serve_mode(arg: str) -> ViewerMode:
    host, port = _split_host_port(arg, "serve")
    if host in (None, "localhost"):
        host = "127.0.0.1"
    try:
        ipaddress.ip_address(host)
    except ValueError:
        raise UsageError(
            f"--rerun serve={arg}: bind address must be an IP address, got {host!r}"
        ) from None
    return ViewerMode("serve", bind_ip=host, port=port or DEFAULT_PORT)


def parse_rerun_option(
    text: str | None,
    recording_path: str | Path | None = None,
    *,
    env: Mapping[str, str] | None = None,
    platform: str | None = None,
    now: datetime | None = None,
) -> ViewerMode:
    """Turn the ``--rerun`` value into a :class:`ViewerMode` (no network, no display touched).

    Parameters
    ----------
    text : the option value; None, ``""`` or ``"auto"`` apply the default rule.
    recording_path : the run's recording, beside which a default ``.rrd`` goes.
    env, platform : for the display check (default: this process).
    now : for the timestamp of a default file name without recording.

    Raises
    ------
    UsageError
        Unknown mode, bad address or port, a save directory that does not exist,
        or ``spawn`` where there is no display.
    """
    text = (text or "").strip()
    kind, sep, arg = text.partition("=")
    if kind in ("", "auto"):
        if has_display(env, platform):
            return ViewerMode("spawn", defaulted=True)
        return ViewerMode("save", path=default_rrd_path(recording_path, now), defaulted=True)
    if kind == "off" and not sep:
        return ViewerMode("off")
    if kind == "spawn" and not sep:
        if not has_display(env, platform):
            raise UsageError(
                "--rerun spawn: no display (DISPLAY and WAYLAND_DISPLAY are unset); "
                "use save=PATH, serve or connect=HOST:PORT instead"
            )
        return ViewerMode("spawn")
    if kind == "connect":
        return ViewerMode("connect", url=_connect_url(arg) if sep else _connect_url(""))
    if kind == "save":
        path = Path(arg) if sep and arg else default_rrd_path(recording_path, now)
        if path.is_dir():
            raise UsageError(f"--rerun save={arg}: {path} is a directory; give a file name")
        if not path.parent.is_dir():
            raise UsageError(f"--rerun save={arg}: directory {path.parent} does not exist")
        return ViewerMode("save", path=path.with_suffix(".rrd") if not path.suffix else path)
    if kind == "serve":
        return _serve_mode(arg if sep else "")
    raise UsageError(
        f"--rerun {text!r}: expected spawn, connect[=HOST:PORT], save=PATH, serve[=ADDR:PORT] or off"
    )


def add_rerun_option(parser: Any) -> None:
    """Add ``--rerun MODE`` to an argparse parser (value parsed later by :func:`parse_rerun_option`)."""
    parser.add_argument("--rerun", metavar="MODE", default=None, help=RERUN_HELP)


def probe_viewer(url: str, timeout_s: float = 1.0) -> None:
    """Raise :class:`UsageError` unless something listens at ``url``'s host and port.

    Rerun's own connect waits 5 s for a viewer that is not there, and again at
    shutdown; one TCP probe turns that into an immediate, clear error.
    """
    parts = urlsplit(url)
    if parts.hostname is None or parts.port is None:
        return
    try:
        with socket.create_connection((parts.hostname, parts.port), timeout=timeout_s):
            pass
    except OSError as err:
        raise UsageError(
            f"--rerun connect: no Rerun viewer at {parts.hostname}:{parts.port} ({err.strerror or err}); "
            "start one with `rerun`, or use save=PATH"
        ) from None


def check_port_free(bind_ip: str, port: int) -> None:
    """Raise :class:`UsageError` if ``bind_ip:port`` cannot be bound.

    Rerun's server only logs a failed bind from its thread and the run would go
    on serving nothing; checking first turns that into a clear error.
    """
    if port == 0:
        return
    family = socket.AF_INET6 if ":" in bind_ip else socket.AF_INET
    try:
        with socket.socket(family, socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((bind_ip, port))
    except OSError as err:
        raise UsageError(
            f"--rerun serve: cannot listen on {bind_ip}:{port} ({err.strerror or err}); "
            "is a viewer already there (use connect) or pick another port (serve=ADDR:PORT)?"
        ) from None


def open_recording(mode: ViewerMode, blueprint: Any, out: TextIO) -> Any:
    """A Rerun ``RecordingStream`` wired to ``mode``'s destination, with the default blueprint."""
    # Both checks come before the 0.5 s import: a user error is reported at once.
    if mode.kind == "connect":
        assert mode.url is not None
        probe_viewer(mode.url)
    if mode.kind == "serve":
        check_port_free(mode.bind_ip, mode.port)
    try:
        import rerun as rr
    except ImportError:
        raise UsageError("--rerun needs the rerun-sdk package (pip install rerun-sdk)") from None
    rec = rr.RecordingStream("ptinertia", recording_id=uuid.uuid4().hex)
    if mode.kind == "save":
        assert mode.path is not None
        rec.save(mode.path, default_blueprint=blueprint)
    elif mode.kind == "serve":
        # rerun joins "IP:PORT" and parses it as a socket address: IPv6 needs its brackets
        bind = f"[{mode.bind_ip}]" if ":" in mode.bind_ip else mode.bind_ip
        server = rr.GrpcServerSink(
            bind_ip=bind, port=mode.port, server_memory_limit=mode.memory_limit
        )
        rec.set_sinks(server, default_blueprint=blueprint)
        print(f"ptinertia: {mode.open_hint()}", file=out)
    elif mode.kind == "connect":
        assert mode.url is not None
        rec.connect_grpc(mode.url, default_blueprint=blueprint)
    elif mode.kind == "spawn":
        rec.spawn(port=mode.port, default_blueprint=blueprint)
    else:
        raise ValueError(f"viewer mode {mode.kind!r} opens no recording")
    return rec
