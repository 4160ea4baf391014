"""An estimator's typed parameters: its `Params` dataclass, checked, read and shown.

An estimator class declares `Params`: a frozen, keyword-only dataclass whose fields are its
parameters, each with a default and, through `testbed.config.key`, its unit, allowed range and a
one-line doc; its `__post_init__` validates (`testbed.config.check_fields` for the declared
intervals, `require` for the rest). The `params` table of an `[[estimators]]` entry (and the
command line's `--estimator NAME --param KEY=VALUE`) sets its keys; the paper built-ins' Params
are their pipeline's config dataclass (testbed.config.pipelines, `kind` excluded, see
testbed.plugins.settings).

- `check`: before anything is simulated, every key given is checked alone (known, typed, in its
  declared interval); a Params whose defaults stand alone (not a pipeline config) is also built
  whole, so its cross-field checks run too. A mistake is a FieldError naming the key and the value.
- `read`: the Params of a params table, for the estimator's constructor.
- `rows`, `text`, `markdown`: what `testbed estimators NAME` prints and the generated parameter
  tables of docs/estimators.md (a test fails when they are stale).
"""
from __future__ import annotations

import dataclasses
import inspect
from typing import Any, Literal, get_args, get_origin, get_type_hints

from testbed.config import check_key, describe_range, from_dict, is_union, show_value, type_name
from testbed.errors import FieldError

# A pipeline config's discriminator: set by testbed.plugins.settings, not a parameter.
NOT_PARAMS = ("kind",)


def params_class(cls: type) -> type | None:
    """The estimator class's `Params` dataclass, or None when it declares none."""
    p = getattr(cls, "Params", None)
    return p if isinstance(p, type) and dataclasses.is_dataclass(p) else None


def pipeline_kind(Params: type) -> str | None:
    """The `[pipeline]` kind whose config dataclass Params is (its `kind: Literal[...]` field), or
    None for a Params that is not a pipeline config."""
    kind = get_type_hints(Params).get("kind")
    return get_args(kind)[0] if kind is not None and get_origin(kind) is Literal else None


def fields(Params: type) -> list[dataclasses.Field]:
    """The parameters of a Params dataclass, in declaration order."""
    return [f for f in dataclasses.fields(Params) if f.name not in NOT_PARAMS]


def check(cls: type, params: dict) -> None:
    """Check a params table against the class's Params (a class without one gets its table as
    it is, unchecked). Raises FieldError naming the key and the value."""
    Params = params_class(cls)
    if Params is None:
        return
    names = {f.name for f in fields(Params)}
    for k, v in params.items():
        if k not in names:
            raise FieldError("", k, v, f"unknown key (known: {', '.join(sorted(names))})")
        check_key(Params, k, v)
    if len(names) == len(dataclasses.fields(Params)):  # not a pipeline config: its defaults stand alone
        from_dict(Params, params)


def read(Params: type, params: dict, entry: str) -> Any:
    """The Params of estimator `entry` from its params table (ConfigError naming entry and key)."""
    return from_dict(Params, params, f"estimator {entry} params")


def rows(Params: type) -> list[tuple[str, str, str, str, str, str]]:
    """(name, type, unit, default, range, doc) of every parameter, as declared."""
    hints = get_type_hints(Params)
    out = []
    for f in fields(Params):
        meta = f.metadata
        if f.default is not dataclasses.MISSING:
            default = "none" if f.default is None else show_value(f.default)
        elif f.default_factory is not dataclasses.MISSING:
            v = f.default_factory()
            default = show_value(v) if not isinstance(v, dict) else ("{}" if not v else ", ".join(f"{k} = {show_value(x)}" for k, x in v.items()))
        else:
            default = "required"
        interval = meta.get("interval")
        allowed = meta.get("range") or (describe_range(*interval) if interval else "")
        tp = hints[f.name]
        literal = [a for a in (get_args(tp) if is_union(tp) else (tp,)) if get_origin(a) is Literal]
        if not allowed and literal:
            allowed = "one of " + ", ".join(show_value(v) for v in get_args(literal[0]))
        out.append((f.name, type_name(hints[f.name]), meta.get("unit", ""), default, allowed, meta.get("doc", "")))
    return out


def text(name: str, cls: type) -> str:
    """`testbed estimators NAME`: one line per parameter (name, type, unit, default, range, doc)."""
    Params = params_class(cls)
    if Params is None:
        return f"{name}: no declared parameters"
    table = [("name", "type", "unit", "default", "range", "doc")] + rows(Params)
    widths = [max(len(r[i]) for r in table) for i in range(5)]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r[:5], widths)) + "  " + r[5] for r in table).rstrip()


def markdown(entries: dict[str, type]) -> str:
    """The parameter tables of docs/estimators.md: one per estimator class {name: class}, the
    names sharing a class in one table."""
    by_class: dict[type, list[str]] = {}
    for name, cls in entries.items():
        if params_class(cls) is not None:
            by_class.setdefault(params_class(cls), []).append(name)
    out = []
    for Params, names in by_class.items():
        out.append("### " + ", ".join(f"`{n}`" for n in names) + "\n")
        kind = pipeline_kind(Params)
        if kind is not None:
            out.append(f'The `[pipeline]` keys of a `kind = "{kind}"` scenario (docs/scenario.md).\n')
        elif inspect.getdoc(Params):
            out.append(inspect.getdoc(Params).splitlines()[0] + "\n")
        out.append("| key | type | unit | default | allowed | meaning |\n|---|---|---|---|---|---|")
        out += [f"| `{k}` | {t} | {u} | {d} | {r} | {m} |".replace("|  |", "| |") for k, t, u, d, r, m in rows(Params)]
        out.append("")
    return "\n".join(out)


def fields_of(p: Any) -> dict:
    """A Params instance as {name: value}, its values as they are (no copy)."""
    return {f.name: getattr(p, f.name) for f in dataclasses.fields(p)}


# The markers of the generated parameter tables in docs/estimators.md.
BEGIN, END = "<!-- generated: testbed estimators --markdown -->", "<!-- end generated -->"


def splice(doc: str, generated: str) -> str:
    """doc with the text between its BEGIN and END markers replaced by generated."""
    head, _, rest = doc.partition(BEGIN + "\n")
    _, _, tail = rest.partition(END)
    return f"{head}{BEGIN}\n{generated}{END}{tail}"
