"""The ``ptinertia`` command line.

Subcommands live in :mod:`ptinertia.commands`, one module each with
``add_parser(subparsers)`` and ``run(args) -> int``; they are imported only
when chosen (a headless replay never imports the viewer or CAN drivers).
A user error prints one line and exits with code 2; a bug still shows its
traceback, because hiding it would hide the bug.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import importlib.util
import os
import platform
import re
import sys
from collections.abc import Iterator, Sequence
from typing import Any

# The numerical work is many small matrices per frame: BLAS threads only add
# overhead there (and compete with the acquisition thread). This module loads no
# numpy, so setting the defaults here still reaches the BLAS library.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from ptinertia.errors import user_error_types  # noqa: E402

# subcommand -> (module, one-line help). Only commands that work are listed.
COMMANDS: dict[str, tuple[str, str]] = {}


def register(name: str, module: str, help_text: str) -> None:
    COMMANDS[name] = (module, help_text)


# Commands (add one line per command, once it works):
register(
    "run", "ptinertia.commands.run", "acquire, track orders and estimate inertia, cog and mass"
)
register("replay", "ptinertia.commands.replay", "re-run dsp and estimator on recorded MCAP logs")
register(
    "excitation",
    "ptinertia.commands.excitation",
    "engine loads on the block per order (gas, inertia, total)",
)
register("modes", "ptinertia.commands.modes", "rigid-body modes of the powertrain on its mounts")
register(
    "simulate",
    "ptinertia.commands.simulate",
    "simulate a bench run and write it as CSV, MF4 or MCAP",
)
register(
    "can-sim",
    "ptinertia.commands.can_sim",
    "simulated bench as a CAN DAQ: send its frames on a bus or to a log",
)
register("pendulum", "ptinertia.commands.pendulum", "inertia and cog from a pendulum test")
register("massline", "ptinertia.commands.massline", "mass, cog, inertia from UFF58 FRFs")
register("compare", "ptinertia.commands.compare", "estimates of any methods side by side")
register("orders", "ptinertia.commands.orders", "order amplitude and phase vs rpm of a recording")
register("simulate-pendulum", "ptinertia.commands.simulate_classic", "simulated pendulum test")
register("simulate-frf", "ptinertia.commands.simulate_classic", "simulated hammer FRFs as UFF58")
register("report", "ptinertia.commands.report", "self-contained HTML report of a run or result")
register("study", "ptinertia.commands.study", "Monte Carlo study of simulated sweeps on Dask")
register("export", "ptinertia.commands.export", "estimate as bench TOML, JSON/CSV or Nastran CONM2")


# Dependencies whose versions ``--version`` prints beside ptinertia's own, as
# python-can's tools do: a bug report then says which decoders and writers ran.
KEY_DEPENDENCIES = (
    "numpy",
    "scipy",
    "python-can",
    "cantools",
    "asammdf",
    "mcap",
    "rerun-sdk",
    "dask",
)

# ``ptinertia run``: / :mod:`x` / ``x``: the docstrings are RST for the API docs,
# the terminal wants plain text
_COMMAND_PREFIX = re.compile(r"^``ptinertia [^`]+``(?: and ``[^`]+``)?:\s*")
_ROLE = re.compile(r":[a-z]+:`~?([^`]+)`")
_LITERAL = re.compile(r"``([^`]+)``")


def plain_help(text: str | None) -> str | None:
    """A command module's RST docstring as the plain text ``--help`` prints.

    The leading "``ptinertia name``:" is dropped (argparse prints the usage line
    just above it) and the first letter is capitalised; roles and literals lose
    their markup.
    """
    if not text:
        return text
    text = _COMMAND_PREFIX.sub("", text.strip())
    text = _LITERAL.sub(r"\1", _ROLE.sub(r"\1", text))
    return text[:1].upper() + text[1:]


class _ParagraphFormatter(argparse.HelpFormatter):
    """Re-wraps each paragraph of a description but keeps the blank lines between them."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        paragraphs = re.split(r"\n\s*\n", text)
        return "\n\n".join(
            super(_ParagraphFormatter, self)._fill_text(p, width, indent) for p in paragraphs
        )


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args: object, **kwargs: object) -> None:
        # subparsers are built by this class too, so every command's help is cleaned here
        if isinstance(kwargs.get("description"), str):
            kwargs["description"] = plain_help(str(kwargs["description"]))
        kwargs.setdefault("formatter_class", _ParagraphFormatter)
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser(argv: Sequence[str]) -> tuple[argparse.ArgumentParser, str | None]:
    parser = _Parser(prog="ptinertia", description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument(
        "--version",
        action=_VersionAction,
        nargs=0,
        help="show the versions of ptinertia and its key dependencies and exit",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    chosen = next((a for a in argv if not a.startswith("-")), None)
    for name, (module, help_text) in COMMANDS.items():
        if name == chosen:
            mod = importlib.import_module(module)
            mod.add_parser(sub, name, help_text)
        else:
            sub.add_parser(name, help=help_text, add_help=False)
    return parser, chosen


class _VersionAction(argparse.Action):
    """argparse's ``version`` action re-wraps the text into one line and looks the
    versions up on every start; this prints one per line, only when asked."""

    def __call__(self, parser: argparse.ArgumentParser, *_: object, **__: object) -> None:
        print(_version())  # on stdout, as argparse's own version action
        parser.exit(0)


def _version() -> str:
    """ptinertia's version, then Python's and the key dependencies' (one line each)."""
    from importlib.metadata import PackageNotFoundError, version

    def installed(dist: str) -> str:
        try:
            return version(dist)
        except PackageNotFoundError:
            return "not installed"

    lines = [f"ptinertia {installed('ptinertia')}", f"  Python {platform.python_version()}"]
    lines += [f"  {dist} {installed(dist)}" for dist in KEY_DEPENDENCIES]
    return "\n".join(lines)


def announce_compiling(command: str) -> Any:
    """One line on stderr when numba starts compiling a kernel (numba broadcasts the event
    after a cache miss only, so loading from its cache says nothing): the first compiled run
    after an install or an update spends 30-35 s there before its first progress line,
    which would look like a hang. Returns the registered listener."""
    # numba is imported here only: the compiled kernels were asked for, so it loads anyway
    from numba.core import event

    class FirstCompile(event.Listener):
        said = False

        def on_start(self, ev: event.Event) -> None:
            if not self.said:
                self.said = True
                print(
                    f"ptinertia {command}: compiling the numba kernels (once after an install "
                    "or an update, 30-35 s; later runs load them from numba's cache)",
                    file=sys.stderr,
                    flush=True,
                )

        def on_end(self, ev: event.Event) -> None:
            pass

    listener = FirstCompile()
    event.register("numba:compile", listener)
    return listener


# Whether this process froze what its first command's imports made (see imports_uncollected).
_frozen: list[bool] = []


@contextlib.contextmanager
def imports_uncollected() -> Iterator[None]:
    """The garbage collector paused while a command's modules load, then what they made
    moved out of its reach (``gc.freeze``, once per process).

    Loading a command imports numpy, scipy, pydantic, mcap and the project: 0.5 s of CPU
    making some 130 000 objects that live as long as the process, over which the collector
    ran 180 times (38 ms) and, once the compiled kernels load, full collections walked them
    all again (57 ms). Measured 2026-11-26 (``ptinertia run --duration 5`` in fresh
    processes, CPU best of 6, the builds interleaved, load 2.5-5): 0.71-0.77 -> 0.63-0.65 s
    with the numpy kernels, 1.15-1.30 -> 0.98-1.07 s compiled. The imports leave
    about 1300 objects of cyclic garbage, frozen with the rest (a few hundred kB, once).
    A collector the caller switched off stays off.
    """
    if not gc.isenabled():
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        if not _frozen:
            gc.freeze()
            _frozen.append(True)
        gc.enable()


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    with imports_uncollected():
        parser, _ = build_parser(argv)
        args = parser.parse_args(argv)
        if not getattr(args, "command", None):
            parser.print_help()
            return 2
        module = importlib.import_module(COMMANDS[args.command][0])
    listener = None
    if os.environ.get("PTINERTIA_NUMBA") == "1":
        if importlib.util.find_spec("numba") is None:
            # asked for the compiled kernels without numba: the numpy ones run (same results)
            print(
                f"ptinertia {args.command}: PTINERTIA_NUMBA=1 but numba is not installed "
                "(pip install 'ptinertia[fast]'): running the numpy kernels",
                file=sys.stderr,
            )
        else:
            listener = announce_compiling(args.command)
    try:
        return int(module.run(args) or 0)
    except user_error_types() as err:
        print(f"ptinertia {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"ptinertia {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader went away (``ptinertia ... | head``): not an error of ours
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    finally:
        if listener is not None:  # (main called again in one process: one listener, one line)
            from numba.core import event

            event.unregister("numba:compile", listener)


if __name__ == "__main__":
    sys.exit(main())
