"""Validation of configuration loaded from TOML into frozen dataclasses, with one message dialect.

Every configuration file of the project (platform spec, scenes and scenarios, backends, runtime,
safety, routes) is checked where it enters through this module, so a user always reads the same
three kinds of message, each naming the file (and the line of the key when the text is known), the
field as a TOML path, the value and what was expected::

    assets/robchair.toml:31: drive.wheel_radius = -0.172: expected a finite number > 0
    run.toml:7: route.turbo: unknown key (value True); expected one of lookahead, speed, waypoints
    run.toml:5: route.waypoints: missing; expected a list of at least 1 [x, y] points of finite numbers

Two ways in:

* :class:`ConfigTable` reads one TOML table field by field (``number``, ``integer``, ``boolean``,
  ``string``, ``vector``, ``points``, ``rows``, sub-tables), for loaders with cross-field rules.
* :func:`load_dataclass` fills a frozen dataclass from a table by its annotations (``float``, ``int``,
  ``bool``, ``str``, fixed-length float tuples and tuples of them, ``X | None``),
  its defaults and the bounds given with :func:`bounds` in each field's metadata; and
  :func:`check_dataclass` applies the same checks to an instance built in code (call it from
  ``__post_init__``).

The error class is :class:`robchair.platform.errors.ConfigError` unless the caller passes a subclass of
``Exception`` of its own package (``sim.errors.ScenarioError`` for scenes).
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import types
import typing
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar, Union

from robchair.platform.errors import ConfigError

T = TypeVar("T")

MISSING: Any = object()
"""Sentinel for "no default": the key is required."""

_BOUNDS_KEY = "robchair.platform.config.bounds"
_MAX_REPR = 80


def _short_repr(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= _MAX_REPR else text[: _MAX_REPR - 3] + "..."


def _join(parent: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{parent}[{key}]"
    return f"{parent}.{key}" if parent else key


_SEGMENT = re.compile(r"([^.\[\]]+)|\[(\d+)\]")


def _path_segments(field: str) -> tuple[str | int, ...]:
    return tuple(m.group(1) if m.group(1) is not None else int(m.group(2)) for m in _SEGMENT.finditer(field))


_KEY = r'(?:[A-Za-z0-9_-]+|"[^"]*"|\'[^\']*\')'
_DOTTED = rf"{_KEY}(?:\s*\.\s*{_KEY})*"
_HEADER_ARRAY = re.compile(rf"^\s*\[\[\s*({_DOTTED})\s*\]\]")
_HEADER_TABLE = re.compile(rf"^\s*\[\s*({_DOTTED})\s*\]")
_KEY_LINE = re.compile(rf"^\s*({_DOTTED})\s*=")
_KEY_PART = re.compile(_KEY)


def _split_dotted(text: str) -> list[str]:
    return [k.strip("\"'") for k in _KEY_PART.findall(text)]


def _index_lines(text: str) -> dict[tuple[str | int, ...], int]:
    """Map each TOML key path (array-of-tables elements as integer indices) to its 1-based line.

    ``tomllib`` keeps no positions, so the headers and ``key =`` lines of the raw text are followed
    the way TOML nests them; keys inside inline tables and multi-line arrays resolve to the line of
    the enclosing key.
    """
    lines: dict[tuple[str | int, ...], int] = {}
    counts: dict[tuple[str | int, ...], int] = {}
    table: tuple[str | int, ...] = ()

    def resolve(keys: list[str]) -> tuple[str | int, ...]:
        # a header below an array of tables refers to its last element: [object.motion] -> object[i].motion
        out: tuple[str | int, ...] = ()
        for k in keys:
            out = (*out, k)
            if out in counts:
                out = (*out, counts[out] - 1)
        return out

    depth = 0  # > 0 inside a multi-line array or inline table: no key lines there
    for n, line in enumerate(text.splitlines(), start=1):
        bare = re.sub(r"#.*$", "", re.sub(r'"[^"]*"|\'[^\']*\'', '""', line))
        if depth == 0:
            m = _HEADER_ARRAY.match(line)
            if m:
                keys = _split_dotted(m.group(1))
                base = (*resolve(keys[:-1]), keys[-1])
                counts[base] = counts.get(base, 0) + 1
                table = (*base, counts[base] - 1)
                lines.setdefault(base, n)
                lines[table] = n
                continue
            m = _HEADER_TABLE.match(line)
            if m:
                table = resolve(_split_dotted(m.group(1)))
                lines.setdefault(table, n)
                continue
            m = _KEY_LINE.match(line)
            if m:
                lines.setdefault((*table, *_split_dotted(m.group(1))), n)
        depth = max(0, depth + bare.count("[") + bare.count("{") - bare.count("]") - bare.count("}"))
    return lines


class ConfigSource:
    """Where configuration values come from: a file (and its text, to find lines) or a label.

    Args:
        name: The file path or a label such as ``"<dict>"``; empty for values built in code.
        text: The raw TOML text, so errors can name the line of the key; ``None`` when unknown.
        error: The exception class raised (``ConfigError`` or a subclass of the caller's package).
    """

    def __init__(self, name: str = "", text: str | None = None, error: type[Exception] = ConfigError) -> None:
        self.name = name
        self.text = text
        self.error_class = error
        self._lines: dict[tuple[str | int, ...], int] | None = None

    def line_of(self, field: str) -> int | None:
        """1-based line of ``field`` (a TOML path such as ``object[2].size``), or of its nearest parent."""
        if self.text is None:
            return None
        if self._lines is None:
            self._lines = _index_lines(self.text)
        path = _path_segments(field)
        while path:
            if path in self._lines:
                return self._lines[path]
            path = path[:-1]
        return None

    def location(self, field: str = "") -> str:
        """``name:line`` (or ``name``) for messages about ``field``; empty if the source has no name."""
        line = self.line_of(field) if field else None
        if not self.name:
            return ""
        return f"{self.name}:{line}" if line is not None else self.name

    def _message(self, field: str, text: str) -> str:
        loc = self.location(field)
        body = f"{field}{text}" if field else text.lstrip(":= ").lstrip()
        return f"{loc}: {body}" if loc else body

    def invalid(self, field: str, value: Any, expected: str) -> Exception:
        """``<file>:<line>: <field> = <value>: expected <what>`` (wrong type or out of range)."""
        return self.error_class(self._message(field, f" = {_short_repr(value)}: expected {expected}"))

    def unknown(self, field: str, value: Any, allowed: Iterable[str]) -> Exception:
        """``<file>:<line>: <field>: unknown key (value <value>); expected one of <allowed>``."""
        names = ", ".join(sorted(allowed)) or "no keys"
        return self.error_class(
            self._message(field, f": unknown key (value {_short_repr(value)}); expected one of {names}")
        )

    def missing(self, field: str, expected: str) -> Exception:
        """``<file>:<line>: <field>: missing; expected <what>``."""
        return self.error_class(self._message(field, f": missing; expected {expected}"))

    def problem(self, field: str, reason: str) -> Exception:
        """``<file>:<line>: <field>: <reason>`` for rules across fields (duplicates, a missing file)."""
        return self.error_class(self._message(field, f": {reason}"))


def load_toml(
    path: Path | str, error: type[Exception] = ConfigError, what: str = "file"
) -> tuple[dict[str, Any], ConfigSource]:
    """Read and parse a TOML file.

    Args:
        path: The file.
        error: Exception class for the messages (see :class:`ConfigSource`).
        what: What the file is, for the "does not exist" message (``"spec file"``, ``"scene"``).

    Returns:
        The parsed tables and a :class:`ConfigSource` that knows the text (for line numbers).

    Raises:
        error: ``<path>: <what> does not exist``, ``<path>: cannot read (...)`` or
            ``<path>: not valid TOML (...)``.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise error(f"{p}: {what} does not exist") from exc
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise error(f"{p}: cannot read ({reason})") from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{p}: not valid TOML ({exc})") from exc
    return data, ConfigSource(str(p), text, error)


def _range_text(gt: float | None, ge: float | None, lt: float | None, le: float | None) -> str:
    lo = f"> {gt:g}" if gt is not None else (f">= {ge:g}" if ge is not None else "")
    hi = f"< {lt:g}" if lt is not None else (f"<= {le:g}" if le is not None else "")
    if lo and hi:
        if ge is not None and le is not None:
            return f"in [{ge:g}, {le:g}]"
        return f"{lo} and {hi}"
    return lo or hi


def _in_range(v: float, gt: float | None, ge: float | None, lt: float | None, le: float | None) -> bool:
    return (
        (gt is None or v > gt)
        and (ge is None or v >= ge)
        and (lt is None or v < lt)
        and (le is None or v <= le)
    )


def _is_real(v: Any) -> bool:
    return not isinstance(v, bool) and isinstance(v, int | float)


class ConfigTable:
    """Typed, checked access to one TOML table.

    Args:
        data: The parsed table.
        source: Where it came from (file and text), for the messages.
        where: Its TOML path (``""`` for the top level, ``"drive"``, ``"object[2]"``).

    Raises:
        ConfigError: (or the source's error class) from :meth:`ConfigSource.invalid` if ``data`` is not
            a table.
    """

    def __init__(self, data: Any, source: ConfigSource | None = None, where: str = "") -> None:
        self.source = source if source is not None else ConfigSource()
        self.where = where
        if not isinstance(data, Mapping):
            raise self.source.invalid(where, data, "a table")
        self.data: Mapping[str, Any] = data

    def field(self, key: str | int) -> str:
        """The TOML path of ``key`` in this table."""
        return _join(self.where, key)

    def __contains__(self, key: object) -> bool:
        return key in self.data

    def keys(self, allowed: Iterable[str], required: Iterable[str] = ()) -> None:
        """Refuse keys not in ``allowed`` and missing ``required`` ones (first offender in sorted order)."""
        allowed = set(allowed)
        for key in sorted(self.data):
            if key not in allowed:
                raise self.source.unknown(self.field(key), self.data[key], allowed)
        for key in sorted(required):
            if key not in self.data:
                raise self.source.missing(self.field(key), "a value")

    def raw(self, key: str, default: Any = MISSING, expected: str = "a value") -> Any:
        """The value of ``key`` unchecked; ``default`` if absent, or an error if it has none."""
        if key in self.data:
            return self.data[key]
        if default is MISSING:
            raise self.source.missing(self.field(key), expected)
        return default

    def invalid(self, key: str | int, expected: str, value: Any = MISSING) -> Exception:
        """The "expected ..." error for ``key`` (its value taken from the table unless given)."""
        if value is MISSING:
            value = self.data.get(key) if isinstance(key, str) else None
        return self.source.invalid(self.field(key), value, expected)

    def problem(self, key: str | int, reason: str) -> Exception:
        """An error about ``key`` that is not one value's type or range."""
        return self.source.problem(self.field(key), reason)

    def number(
        self,
        key: str,
        default: Any = MISSING,
        *,
        gt: float | None = None,
        ge: float | None = None,
        lt: float | None = None,
        le: float | None = None,
    ) -> float:
        """A finite real number (an integer is accepted), optionally within bounds."""
        rng = _range_text(gt, ge, lt, le)
        expected = f"a finite number {rng}".rstrip()
        if key not in self.data and default is not MISSING:
            return typing.cast(float, default) if default is None else float(default)
        v = self.raw(key, expected=expected)
        if not _is_real(v) or not math.isfinite(v) or not _in_range(float(v), gt, ge, lt, le):
            raise self.invalid(key, expected, v)
        return float(v)

    def integer(
        self,
        key: str,
        default: Any = MISSING,
        *,
        gt: int | None = None,
        ge: int | None = None,
        lt: int | None = None,
        le: int | None = None,
    ) -> int:
        """An integer (not a bool, not a float), optionally within bounds."""
        expected = f"an integer {_range_text(gt, ge, lt, le)}".rstrip()
        if key not in self.data and default is not MISSING:
            return typing.cast(int, default)
        v = self.raw(key, expected=expected)
        if isinstance(v, bool) or not isinstance(v, int) or not _in_range(v, gt, ge, lt, le):
            raise self.invalid(key, expected, v)
        return v

    def boolean(self, key: str, default: Any = MISSING) -> bool:
        """``true`` or ``false``."""
        if key not in self.data and default is not MISSING:
            return typing.cast(bool, default)
        v = self.raw(key, expected="true or false")
        if not isinstance(v, bool):
            raise self.invalid(key, "true or false", v)
        return v

    def string(self, key: str, default: Any = MISSING, *, choices: Sequence[str] | None = None) -> str:
        """A non-empty string, optionally one of ``choices``."""
        expected = f"one of {', '.join(choices)}" if choices is not None else "a non-empty string"
        if key not in self.data and default is not MISSING:
            return typing.cast(str, default)
        v = self.raw(key, expected=expected)
        if not isinstance(v, str) or not v or (choices is not None and v not in choices):
            raise self.invalid(key, expected, v)
        return v

    def vector(
        self,
        key: str,
        n: int | Sequence[int],
        default: Any = MISSING,
        *,
        gt: float | None = None,
        ge: float | None = None,
        lt: float | None = None,
        le: float | None = None,
    ) -> tuple[float, ...]:
        """A list of ``n`` (or any of the lengths in ``n``) finite numbers, each within the bounds."""
        ns = (n,) if isinstance(n, int) else tuple(n)
        count = " or ".join(str(k) for k in ns)
        rng = _range_text(gt, ge, lt, le)
        expected = f"a list of {count} finite numbers" + (f" {rng}" if rng else "")
        if key not in self.data and default is not MISSING:
            return (
                typing.cast(tuple[float, ...], default)
                if default is None
                else tuple(float(a) for a in default)
            )
        v = self.raw(key, expected=expected)
        ok = (
            isinstance(v, list | tuple)
            and len(v) in ns
            and all(_is_real(a) and math.isfinite(a) and _in_range(float(a), gt, ge, lt, le) for a in v)
        )
        if not ok:
            raise self.invalid(key, expected, v)
        return tuple(float(a) for a in v)

    def points(
        self, key: str, default: Any = MISSING, *, min_count: int = 1
    ) -> tuple[tuple[float, float], ...]:
        """A list of at least ``min_count`` finite ``[x, y]`` points."""
        expected = f"a list of at least {min_count} [x, y] points of finite numbers"
        if key not in self.data and default is not MISSING:
            return typing.cast(tuple[tuple[float, float], ...], default)
        v = self.raw(key, expected=expected)
        ok = (
            isinstance(v, list | tuple)
            and len(v) >= min_count
            and all(
                isinstance(p, list | tuple)
                and len(p) == 2
                and all(_is_real(a) and math.isfinite(a) for a in p)
                for p in v
            )
        )
        if not ok:
            raise self.invalid(key, expected, v)
        return tuple((float(p[0]), float(p[1])) for p in v)

    def rows(
        self, key: str, cols: int, default: Any = MISSING, *, count: int | None = None, min_count: int = 1
    ) -> tuple[tuple[float, ...], ...]:
        """A list of ``count`` (or at least ``min_count``) rows of ``cols`` finite numbers each."""
        how_many = str(count) if count is not None else f"at least {min_count}"
        expected = f"a list of {how_many} lists of {cols} finite numbers"
        if key not in self.data and default is not MISSING:
            return typing.cast(tuple[tuple[float, ...], ...], default)
        v = self.raw(key, expected=expected)
        ok = (
            isinstance(v, list | tuple)
            and (len(v) == count if count is not None else len(v) >= min_count)
            and all(
                isinstance(r, list | tuple)
                and len(r) == cols
                and all(_is_real(a) and math.isfinite(a) for a in r)
                for r in v
            )
        )
        if not ok:
            raise self.invalid(key, expected, v)
        return tuple(tuple(float(a) for a in r) for r in v)

    def table(self, key: str, default: Any = MISSING) -> ConfigTable:
        """The sub-table ``key`` (``default``, e.g. ``{}``, if absent)."""
        v = self.raw(key, default, expected="a table")
        if not isinstance(v, Mapping):
            raise self.invalid(key, "a table", v)
        return ConfigTable(v, self.source, self.field(key))

    def tables(self, key: str, default: Any = MISSING) -> list[ConfigTable]:
        """The array of tables ``key`` (``[[key]]``), each addressed as ``key[i]``."""
        v = self.raw(key, default, expected=f"an array of tables ([[{key}]])")
        if not isinstance(v, list):
            raise self.invalid(key, f"an array of tables ([[{key}]])", v)
        out = []
        for i, item in enumerate(v):
            if not isinstance(item, Mapping):
                raise self.source.invalid(_join(self.field(key), i), item, "a table")
            out.append(ConfigTable(item, self.source, _join(self.field(key), i)))
        return out


# --------------------------------------------------------------------------------------------- dataclasses


def bounds(
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: Sequence[str] | None = None,
) -> dict[str, Any]:
    """Field metadata giving the allowed range (numbers, and each element of a tuple) or choices.

    Example::

        @dataclass(frozen=True)
        class SafetyLimits:
            margin_m: float = field(default=0.15, metadata=bounds(gt=0))
    """
    return {_BOUNDS_KEY: {"gt": gt, "ge": ge, "lt": lt, "le": le, "choices": choices}}


def _optional_inner(tp: Any) -> Any:
    """``X`` for ``X | None`` / ``Optional[X]``, else ``None``."""
    if typing.get_origin(tp) in (Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return args[0]
    return None


def _float_row(tp: Any) -> int:
    """Length of a fixed-length ``tuple[float, ...]`` type (``tuple[float, float]`` -> 2), else 0."""
    args = typing.get_args(tp)
    if typing.get_origin(tp) is tuple and args and Ellipsis not in args and all(a is float for a in args):
        return len(args)
    return 0


def _read_typed(table: ConfigTable, key: str, tp: Any, default: Any, meta: Mapping[str, Any]) -> Any:
    rng = {k: meta.get(k) for k in ("gt", "ge", "lt", "le")}
    inner = _optional_inner(tp)
    if inner is not None:
        if key not in table.data:
            return default if default is not MISSING else None
        tp = inner
    if tp is bool:
        return table.boolean(key, default)
    if tp is int:
        return table.integer(key, default, **rng)
    if tp is float:
        return table.number(key, default, **rng)
    if tp is str:
        return table.string(key, default, choices=meta.get("choices"))
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis and _float_row(args[0]) == 2:
            return table.points(key, default)
        if len(args) == 2 and args[1] is Ellipsis and _float_row(args[0]):
            return table.rows(key, _float_row(args[0]), default)
        if args and len({_float_row(a) for a in args}) == 1 and _float_row(args[0]):
            return table.rows(key, _float_row(args[0]), default, count=len(args))
        if len(args) == 2 and args[1] is Ellipsis and args[0] is float:
            v = table.raw(key, default)
            if v is default and key not in table.data:
                return default
            if not isinstance(v, list | tuple):
                raise table.invalid(key, "a list of finite numbers", v)
            return table.vector(key, len(v), **rng)
        if args and all(a is float for a in args):
            return table.vector(key, len(args), default, **rng)
    raise TypeError(f"load_dataclass: field {table.field(key)!r} has an unsupported type {tp!r}")


def load_dataclass(
    cls: type[T],
    data: Mapping[str, Any] | ConfigTable,
    source: ConfigSource | None = None,
    where: str = "",
    **overrides: Any,
) -> T:
    """Build the dataclass ``cls`` from a TOML table, checking every key against its fields.

    Args:
        cls: A dataclass whose fields are annotated with ``float``, ``int``, ``bool``, ``str``,
            ``tuple[float, float, float]`` (any fixed length), ``tuple[float, ...]``, tuples of
            fixed-length float tuples (``tuple[tuple[float, float], ...]``, or a fixed number of
            them), or ``X | None`` of these. Bounds and choices come
            from :func:`bounds` in the field metadata; defaults from the dataclass.
        data: The table (or a :class:`ConfigTable`, whose source and path are then used).
        source: File and text of the table, for messages.
        where: TOML path of the table (``"safety"``).
        **overrides: Values that replace the table's (e.g. from command-line options), checked alike.

    Returns:
        The instance (its ``__post_init__`` runs as usual).

    Raises:
        ConfigError: (or the source's error class) for an unknown key, a missing field without
            default, a wrong type or a value out of bounds.
    """
    if isinstance(data, ConfigTable):
        table = data
        if overrides:
            table = ConfigTable({**data.data, **overrides}, data.source, data.where)
    else:
        table = ConfigTable({**data, **overrides}, source, where)
    fields = [f for f in dataclasses.fields(cls) if f.init]  # type: ignore[arg-type]
    table.keys({f.name for f in fields})
    hints = typing.get_type_hints(cls)
    kwargs: dict[str, Any] = {}
    for f in fields:
        default: Any = MISSING
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        if f.name not in table.data and default is not MISSING:
            continue
        kwargs[f.name] = _read_typed(table, f.name, hints[f.name], default, f.metadata.get(_BOUNDS_KEY, {}))
    return cls(**kwargs)


def check_dataclass(obj: Any, where: str = "", source: ConfigSource | None = None) -> None:
    """Apply :func:`load_dataclass`'s type and bounds checks to an instance built in code.

    Meant for ``__post_init__``: ``check_dataclass(self, "safety")``.

    Raises:
        ConfigError: (or the source's error class) naming the first field that does not fit.
    """
    hints = typing.get_type_hints(type(obj))
    fields = [f for f in dataclasses.fields(obj) if f.init]
    # in code, tuples stand where TOML has lists
    values = {f.name: _as_lists(getattr(obj, f.name)) for f in fields}
    table = ConfigTable(values, source, where)
    for f in fields:
        if values[f.name] is None and _optional_inner(hints[f.name]) is not None:
            continue
        _read_typed(table, f.name, hints[f.name], MISSING, f.metadata.get(_BOUNDS_KEY, {}))


def _as_lists(v: Any) -> Any:
    return [_as_lists(a) for a in v] if isinstance(v, tuple) else v
