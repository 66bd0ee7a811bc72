"""The Rerun view's options: where it goes by default, the addresses it connects to and
serves on (127.0.0.1 unless told), the errors a bad option gets.

No viewer is ever started: the sink saves to a file or serves on 127.0.0.1 only.
"""

from __future__ import annotations

import io
import socket
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import pytest
from support.viewer_checks import closed_port

from ptinertia.errors import UsageError, user_error_types
from ptinertia.viewer import options as viewer_options
from ptinertia.viewer.options import open_recording, parse_rerun_option
from ptinertia.viewer.rerun_sink import ViewerMode, make_viewer_sink

NO_DISPLAY: dict[str, str] = {}
X11 = {"DISPLAY": ":0"}


# -- option parsing ---------------------------------------------------------------------------


@pytest.mark.parametrize("text", [None, "", "auto"])
def test_default_never_spawns_without_a_display(text, tmp_path):
    mode = parse_rerun_option(text, tmp_path / "run.mcap", env=NO_DISPLAY, platform="linux")
    assert mode.kind == "save" and mode.defaulted
    assert mode.path == tmp_path / "run.rrd"
    assert mode.open_hint() == f"Rerun view saved to {mode.path}; open it with: rerun {mode.path}"


def test_default_without_recording_saves_a_timestamped_file_here():
    mode = parse_rerun_option(
        None, None, env=NO_DISPLAY, platform="linux", now=datetime(2024, 1, 2, 3, 4, 5)
    )
    assert mode.path == Path.cwd() / "ptinertia-20240102-030405.rrd"


@pytest.mark.parametrize("env", [X11, {"WAYLAND_DISPLAY": "wayland-0"}])
def test_default_spawns_where_there_is_a_display(env):
    mode = parse_rerun_option(None, None, env=env, platform="linux")
    assert (mode.kind, mode.defaulted) == ("spawn", True)


def test_explicit_spawn_without_display_is_a_user_error():
    with pytest.raises(UsageError, match="no display"):
        parse_rerun_option("spawn", None, env=NO_DISPLAY, platform="linux")
    assert parse_rerun_option("spawn", None, env=NO_DISPLAY, platform="darwin").kind == "spawn"


def test_make_viewer_sink_headless_saves(monkeypatch, tmp_path):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    sink = make_viewer_sink(None, tmp_path / "run.mcap")
    assert sink is not None and sink.mode.kind == "save" and sink.mode.path == tmp_path / "run.rrd"
    assert make_viewer_sink("off") is None


@pytest.mark.parametrize(
    ("text", "url"),
    [
        ("connect", "rerun+http://127.0.0.1:9876/proxy"),
        ("connect=10.0.0.5:9000", "rerun+http://10.0.0.5:9000/proxy"),
        ("connect=viewer-host", "rerun+http://viewer-host:9876/proxy"),
        ("connect=:9877", "rerun+http://127.0.0.1:9877/proxy"),
        ("connect=[::1]:9877", "rerun+http://[::1]:9877/proxy"),
        ("connect=rerun+https://example.org/proxy", "rerun+https://example.org/proxy"),
    ],
)
def test_connect_addresses(text, url):
    assert parse_rerun_option(text).url == url


@pytest.mark.parametrize(
    ("text", "bind", "port"),
    [
        ("serve", "127.0.0.1", 9876),
        ("serve=9000", "127.0.0.1", 9000),
        ("serve=localhost:9001", "127.0.0.1", 9001),
        ("serve=0.0.0.0:9002", "0.0.0.0", 9002),
        ("serve=[::1]:9003", "::1", 9003),
    ],
)
def test_serve_binds_localhost_unless_told(text, bind, port):
    mode = parse_rerun_option(text)
    assert (mode.kind, mode.bind_ip, mode.port) == ("serve", bind, port)


def test_save_path(tmp_path):
    assert parse_rerun_option(f"save={tmp_path / 'a.rrd'}").path == tmp_path / "a.rrd"
    assert parse_rerun_option(f"save={tmp_path / 'a'}").path == tmp_path / "a.rrd"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("bogus", "expected spawn, connect"),
        ("save=/no/such/dir/x.rrd", "does not exist"),
        ("serve=myhost:9000", "must be an IP address"),
        ("serve=:70000", "port must be 1-65535"),
        ("connect=localhost:x1", "port must be 1-65535"),
        ("connect=http://host:9876", "URL scheme"),
        ("off=1", "expected spawn"),
    ],
)
def test_bad_options_are_user_errors(text, message):
    with pytest.raises(UsageError, match=message):
        parse_rerun_option(text)
    assert issubclass(UsageError, user_error_types())


def test_save_into_a_directory_is_refused(tmp_path):
    with pytest.raises(UsageError, match="is a directory"):
        parse_rerun_option(f"save={tmp_path}")


def test_importing_the_viewer_does_not_import_rerun():
    code = "import sys, ptinertia.viewer.rerun_sink; print('rerun' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_connect_to_nothing_fails_fast_instead_of_hanging(monkeypatch):
    """One TCP probe with a short timeout, refused at once, before Rerun's own 5 s connect."""
    timeouts = []
    create_connection = socket.create_connection

    def probe(address, timeout, *args, **kwargs):
        timeouts.append(timeout)
        return create_connection(address, timeout, *args, **kwargs)

    monkeypatch.setattr(viewer_options.socket, "create_connection", probe)
    mode = parse_rerun_option(f"connect=127.0.0.1:{closed_port()}")
    with pytest.raises(UsageError, match=r"no Rerun viewer at 127\.0\.0\.1"):
        open_recording(mode, None, io.StringIO())
    assert len(timeouts) == 1 and 0 < timeouts[0] <= 1.0


def _listening_sockets_of_this_process() -> list[str]:
    """Local ``address:port`` (hex, as in /proc/net/tcp*) of this process's listening TCP sockets."""
    fd_dir = Path("/proc/self/fd")
    inodes = set()
    for fd in fd_dir.iterdir():
        try:
            link = fd.readlink().as_posix()
        except OSError:
            continue
        if link.startswith("socket:["):
            inodes.add(link[8:-1])
    out = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:  # 0A = LISTEN
                out.append(f[1])
    return out


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc")
def test_serve_listens_on_loopback_only():
    before = set(_listening_sockets_of_this_process())
    mode = ViewerMode("serve", bind_ip="127.0.0.1", port=0, memory_limit="16MiB")
    rec = open_recording(mode, None, io.StringIO())
    try:
        # Rerun's server socket is listening by the time open_recording returns (serving
        # runs on its thread, binding does not), so one look suffices
        new = set(_listening_sockets_of_this_process()) - before
        # 127.0.0.1, and nothing on 0.0.0.0 or ::
        assert {address.split(":")[0] for address in new} == {"0100007F"}
    finally:
        rec.disconnect()
