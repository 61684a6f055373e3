"""The `toolkit` command. One module per command; each adds itself to `app`.

Errors the user can act on (ToolkitError) print as one line and exit 1; so does anything
unexpected, unless TOOLKIT_DEBUG=1 asks for the traceback.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, TypeGuard, get_args, get_origin

import typer
import typer.core

if TYPE_CHECKING:
    from typer._click import Context
    from typer._coercion import RuntimeParam, TypeDescriptor
    from typer.core import _TyperParameter
    from typer.models import ParameterInfo

# Typer (0.2x) prints every argument's Python type beside its name (`DATASET <list[Path]>`);
# arguments are named for what they are and their help says the rest, as argparse shows them.
# (Options say what they take with an explicit metavar, flags take nothing.)
typer.core.TyperArgument.display_type_rich = lambda self, ctx: None  # type: ignore[method-assign,assignment,unused-ignore]


class _PlainValues:
    """Typer's coercion of one parameter (`RuntimeParam.coerce`) for the plain values every
    command takes: a str for a `str` (several for a `list[str]`), a non-empty str (or
    several, for `list[Path]`) for a `Path` (Path(value), then typer's own checks,
    `coerce_cli_path`), a default already of its `int`/`float`/`bool` type as it is;
    anything else, and every other annotation, by typer's own pydantic TypeAdapter (built
    then). The same values as typer gives, without loading pydantic and building an adapter
    per parameter in every command's start (0.06-0.08 s of CPU, `toolkit map`'s included)."""

    def __init__(self, descriptor: TypeDescriptor) -> None:
        self.descriptor = descriptor
        self._typer: RuntimeParam | None = None  # typer's own, on use

    def _own(self) -> RuntimeParam:
        if self._typer is None:
            self._typer = _typer_runtime_param(self.descriptor)
        return self._typer

    def coerce(self, value: object, param: _TyperParameter, ctx: Context) -> object:
        many = param.multiple or param.nargs == -1
        if value is None:  # as typer's RuntimeParam.coerce
            return () if many else None
        if many and isinstance(value, str):
            return self._own().coerce(value, param, ctx)  # typer's error
        annotation: object = self.descriptor.annotation
        if get_origin(annotation) is list and isinstance(value, list | tuple):
            if get_args(annotation) == (str,) and all(type(v) is str for v in value):
                return list(value)  # repeated text options (KEY=VALUE)
            if all(_plain_path(v) for v in value):
                return [self._path(v, param, ctx) for v in value]
        elif annotation is Path and _plain_path(value):
            return self._path(value, param, ctx)
        elif annotation in (str, int, float, bool) and type(value) is annotation:
            return value  # a str as given, a default of its type
        return self._own().coerce(value, param, ctx)

    def _path(self, value: str, param: _TyperParameter, ctx: Context) -> object:
        info = self.descriptor.parameter_info
        return _coerce_cli_path(Path(value), info, path_type=Path, param=param, ctx=ctx)


def _plain_path(value: object) -> TypeGuard[str]:
    return isinstance(value, str) and value != ""


def _plain(annotation: object, info: ParameterInfo) -> bool:
    """An annotation `_PlainValues` coerces (others go to typer's adapters at once)."""
    if info.parser is not None or info.min is not None or info.max is not None:
        return False
    if get_origin(annotation) is list:
        return get_args(annotation) == (str,) or (
            get_args(annotation) == (Path,) and info.path_type is None
        )
    if annotation is Path:
        return info.path_type is None
    return annotation in (str, int, float, bool)


try:  # typer's internals (0.2x); when they differ, typer coerces everything itself
    from typer._param_types import coerce_cli_path as _coerce_cli_path

    _typer_runtime_param = typer.core.build_runtime_param  # type: ignore[attr-defined,unused-ignore]

    def _runtime_param(descriptor: TypeDescriptor) -> RuntimeParam | _PlainValues:
        if descriptor.file_annotation is None and _plain(
            descriptor.annotation, descriptor.parameter_info
        ):
            return _PlainValues(descriptor)
        return _typer_runtime_param(descriptor)

    typer.core.build_runtime_param = _runtime_param  # type: ignore[attr-defined,assignment,unused-ignore]
except (ImportError, AttributeError):  # pragma: no cover
    pass

app = typer.Typer(
    name="toolkit",
    help="2D laser robot logs: import to Parquet, align scans, build maps, learn places, report.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain help, like click and argparse: flags as flags, text rewrapped
    context_settings={"help_option_names": ["-h", "--help"]},
)


def version() -> str:
    """The installed package's version (the source tree's when run from a checkout)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed("laser-toolkit")
    except PackageNotFoundError:
        from toolkit import __version__

        return __version__


def _show_version(value: bool) -> None:
    if value:
        typer.echo(f"toolkit {version()}")
        raise typer.Exit()


@app.callback()
def _root(
    _version: Annotated[
        bool,
        typer.Option(
            "--version",
            "-V",
            callback=_show_version,
            is_eager=True,
            help="Print the version and exit.",
        ),
    ] = False,
) -> None:
    """2D laser robot logs: import to Parquet, align scans, build maps, learn places, report."""


# Command modules register themselves on `app` when imported.
from toolkit.app.cli import import_cmd as _import_cmd  # noqa: E402,F401
from toolkit.app.cli import info_cmd as _info_cmd  # noqa: E402,F401
from toolkit.app.cli import label_cmd as _label_cmd  # noqa: E402,F401
from toolkit.app.cli import map_cmd as _map_cmd  # noqa: E402,F401
from toolkit.app.cli import report_cmd as _report_cmd  # noqa: E402,F401
from toolkit.app.cli import simulate_cmd as _simulate_cmd  # noqa: E402,F401


def fail(message: str) -> None:
    """Print one line to stderr and exit 1."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(1)


def main() -> None:
    from toolkit.app import signals
    from toolkit.errors import ToolkitError

    try:
        # Without standalone mode click returns exit codes (typer.Exit, Ctrl-C) instead of
        # raising SystemExit, so that errors below can be printed as one line.
        rc = app(prog_name="toolkit", standalone_mode=False)
        if rc == 130:
            typer.echo(signals.stopped_message(), err=True)
            rc = signals.exit_code()
        if isinstance(rc, int) and rc != 0:
            sys.exit(rc)
    except ToolkitError as e:
        typer.echo(f"error: {e.line()}", err=True)
        sys.exit(1)
    except typer.Exit as e:
        sys.exit(e.exit_code)
    except (typer.Abort, KeyboardInterrupt):
        signals.exit_stopped()
    except Exception as e:  # a usage error, or a bug: still one line
        if signals.received is not None:
            # the stop landed inside an import or a library's C code, which wrapped it (an
            # extension module's "initialization failed"): a stopped command all the same
            signals.broken_import = isinstance(e, ImportError)
            signals.exit_stopped()
        show = getattr(e, "format_message", None)
        if type(e).__name__ == "NoArgsIsHelpError" and show is not None:
            typer.echo(show())  # `toolkit` alone: the help, as `--help` prints it
            sys.exit(0)
        if show is not None:  # click's exceptions (typer bundles its own click)
            typer.echo(f"error: {show()} (see --help)", err=True)
            sys.exit(1)
        if os.environ.get("TOOLKIT_DEBUG"):
            raise
        typer.echo(
            f"error: internal error {type(e).__name__}: {e} (TOOLKIT_DEBUG=1 shows where)",
            err=True,
        )
        sys.exit(1)
