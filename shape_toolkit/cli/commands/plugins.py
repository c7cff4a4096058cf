"""``shape-toolkit plugins list [--json]`` (every family, plus the matching pipelines) and
``shape-toolkit plugins show NAME`` (parameters with defaults, types, allowed values and descriptions from the
class's ``parameter_constraints``; presets; declared spectrum)."""

from __future__ import annotations

import argparse
import inspect
from typing import Any

from shape_toolkit.api.registry import get_registry
from shape_toolkit.cli.commands._common import print_json
from shape_toolkit.errors import ParameterError, PluginError, ToolkitError
from shape_toolkit.validation import jsonable


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help="list the registered plugins and pipelines, or show one")
    psub = p.add_subparsers(dest="plugins_command", metavar="ACTION")
    lst = psub.add_parser("list", help="list plugins by family, and the matching pipelines")
    lst.add_argument("--json", action="store_true", help="print {family: [names...], 'pipelines': [...]}")
    lst.set_defaults(func=run)
    show = psub.add_parser("show", help="parameters, defaults, presets and declared spectrum of a plugin")
    show.add_argument("name", help="plugin or pipeline name (see plugins list)")
    show.add_argument("--family", help="only this family (when a name exists in several)")
    show.add_argument("--json", action="store_true", help="print JSON")
    show.set_defaults(func=show_cmd)
    p.set_defaults(func=run, json=False)


def run(args: argparse.Namespace) -> int:
    from shape_toolkit.pipeline import PRESETS

    reg = get_registry()
    fams: dict[str, Any] = dict(reg.families())
    fams["pipelines"] = sorted(PRESETS)
    if args.json:
        print_json(fams)
        return 0
    width = max(len(f) for f in fams)
    for fam, names in fams.items():
        print(f"{fam:<{width}}  {', '.join(names) if names else '(none)'}")
    for name, err in reg.broken.items():
        print(f"broken plugin {name}: {err}")
    print("details: shape-toolkit plugins show NAME")
    return 0


def plugin_info(family: str, name: str) -> dict[str, Any]:
    """What ``plugins show`` prints for one plugin: doc line, parameters with defaults, presets and
    the spectrum it declares with its default parameters (None when it needs none)."""
    reg = get_registry()
    cls = reg.get(family, name)
    declared = getattr(cls, "parameter_constraints", None) or {}
    params = []
    for par in list(inspect.signature(cls.__init__).parameters.values())[1:]:
        if par.kind in (par.VAR_POSITIONAL, par.VAR_KEYWORD):
            continue
        decl = declared.get(par.name)
        params.append({"name": par.name,
                       "default": None if par.default is par.empty else jsonable(par.default),
                       "required": par.default is par.empty,
                       "type": decl.type_name if decl else None,
                       "allowed": decl.describe() if decl else None,
                       "doc": decl.doc if decl else None})
    spectra: Any = None
    try:
        spectra = [s.to_dict() for s in cls().spectrum_specs()] if hasattr(cls, "spectrum_specs") else []
    except (TypeError, ToolkitError) as exc:  # required parameters: the spec depends on them
        spectra = f"depends on the parameters ({' '.join(str(exc).split())[:80]})"
    doc = (inspect.getdoc(cls) or "").strip().split("\n\n")[0].replace("\n", " ")
    presets = dict(getattr(cls, "presets", {}) or {})
    defaults = {p["name"]: p["default"] for p in params}
    return {
        "family": family,
        "name": name,
        "class": f"{cls.__module__}.{cls.__qualname__}",
        "entry_point": reg.entry_point(family, name),
        "doc": doc,
        "randomized": any(p["name"] == "random_state" for p in params),
        "parameters": params,
        "presets": jsonable(presets),
        "preset_differences": {name: preset_differences(defaults, jsonable(vals)) for name, vals in presets.items()},
        "spectra": spectra,
    }


def preset_differences(defaults: dict[str, Any], values: dict[str, Any]) -> dict[str, list[Any]]:
    """``{param: [default, preset value]}`` for the parameters a preset sets to something else than the default."""
    return {k: [defaults.get(k), v] for k, v in values.items() if k not in defaults or defaults[k] != v}


def _literal_sibling(name: str, presets: dict[str, Any]) -> str | None:
    """The pipeline a literal ``NAME-thesis`` chain is the counterpart of, or the literal chain of ``NAME``."""
    if name.endswith("-thesis") and name[: -len("-thesis")] in presets:
        return name[: -len("-thesis")]
    return f"{name}-thesis" if f"{name}-thesis" in presets else None


def _stage_differences(first: dict[str, Any], second: dict[str, Any]) -> dict[str, list[Any]]:
    """``{stage: [in first, in second]}`` (None: no such stage) for the stages two pipeline specs set differently."""
    stages = [k for k in dict.fromkeys([*first, *second]) if k != "description"]
    return {k: [jsonable(first.get(k)), jsonable(second.get(k))] for k in stages if first.get(k) != second.get(k)}


def pipeline_info(name: str) -> dict[str, Any]:
    """What ``plugins show`` prints for a pipeline preset: its stages and the spectra they declare."""
    from shape_toolkit.pipeline import PRESETS, load_pipeline

    spec = PRESETS[name]
    pipe = load_pipeline(name)
    sibling = _literal_sibling(name, PRESETS)
    return {
        "family": "pipelines",
        "name": name,
        "doc": spec.get("description", ""),
        "stages": {k: jsonable(v) for k, v in spec.items() if k != "description"},
        "compared_with": sibling,
        "stage_differences": _stage_differences(PRESETS[sibling], spec) if sibling else {},
        "spectra": [s.to_dict() for s in pipe.spectrum_specs()],
    }


def show_cmd(args: argparse.Namespace) -> int:
    from shape_toolkit.pipeline import PRESETS

    reg = get_registry()
    fams = [args.family] if args.family else [*reg.families(), "pipelines"]
    found = []
    for fam in fams:
        if fam == "pipelines":
            if args.name in PRESETS:
                found.append(pipeline_info(args.name))
        elif fam not in reg.families():
            raise ParameterError(f"--family {fam!r}: choose one of {', '.join([*reg.families(), 'pipelines'])}")
        elif reg.has(fam, args.name):
            found.append(plugin_info(fam, args.name))
    if not found:
        raise PluginError(f"no plugin or pipeline named {args.name!r}; see 'shape-toolkit plugins list'")
    if args.json:
        print_json(found if len(found) > 1 else found[0])
        return 0
    for i, info in enumerate(found):
        if i:
            print()
        print(f"{info['name']} ({info['family']}): {info['doc']}")
        if "stages" in info:
            for stage, st in info["stages"].items():
                print(f"  stage {stage}: {st}")
            if info["compared_with"]:
                print(f"  {info['compared_with']} -> {info['name']}:")
                for stage, (a, b) in info["stage_differences"].items():
                    print(f"    stage {stage}: {a if a else '(none)'} -> {b if b else '(none)'}")
        else:
            ep = f"  [entry point {info['entry_point']}]" if info["entry_point"] else ""
            print(f"  class: {info['class']}{ep}")
            print("  parameters:" if info["parameters"] else "  parameters: none")
            for par in info["parameters"]:
                line = f"    {par['name']} = {'(required)' if par['required'] else repr(par['default'])}"
                if par["type"] is not None:  # declared: type, allowed values, one-line description
                    line += f"  [{par['type']}] {par['allowed']}: {par['doc']}"
                print(line)
            for pname, pvals in info["presets"].items():
                print(f"  preset {pname}: {', '.join(f'{k}={v!r}' for k, v in pvals.items())}")
                diff = info["preset_differences"][pname]
                changes = "; ".join(f"{k} {a!r} -> {b!r}" for k, (a, b) in diff.items())
                print(f"    default -> {pname}: {changes or 'no difference (the defaults are these values)'}")
        sp = info["spectra"]
        if isinstance(sp, str):
            print(f"  spectrum: {sp}")
        elif sp:
            for s in sp:
                print(f"  spectrum: {', '.join(f'{k}={v}' for k, v in s.items())}")
        else:
            print("  spectrum: none")
    return 0
