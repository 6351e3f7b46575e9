"""pipeline.yaml: load and check the DAG, find each step's declaration, resolve params.

A packaged step is declared once in go_pipeline.steps.registry (params class, outputs, skip rules, version
override): its params in pipeline.yaml, the profiles and ``--set`` are checked against the class (known
name, type, range) and resolved into an instance of it. A step of your own names its outputs and params'
defaults in pipeline.yaml (each default gives its type) and may declare ``VERSION`` / ``SKIP_IF_*`` in its
module, read with ast without importing it.
Everything here is cheap (yaml + ast + the torch-free params classes), so ``status`` and a no-op ``run``
never import torch or a step.
"""

from __future__ import annotations

import ast
import importlib.util
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from go_core.config import SettingError, check_value, fields_of, from_mapping, to_mapping
from go_core.errors import PipelineError, first_line

INSTALLED_STEPS = "go_pipeline.steps"  # the package of the steps that ship with go-pipeline
ALLOW_CUSTOM_STEPS_ENV = "GO_ALLOW_CUSTOM_STEPS"  # "1": same as --allow-custom-steps
SCENE_INPUT = "@scene"  # the pseudo-input naming the scene folder itself (a step may be called `scene`)
_STEP_KEYS = {"function", "inputs", "outputs", "params", "description"}
_TOP_KEYS = {"version", "steps", "profiles"}
RESERVED_OUTPUTS = {"manifest.json"}
# steps renamed since earlier versions: old name -> (new name, why); an old name in --set, --until, --force, a
# profile or a work dir's remembered params gets one line naming the new one
RENAMED_STEPS = {
    "lora": ("tune", "it tunes the repair model: LoRA for sd15, a full fine-tune for the compact model"),
}
# params renamed since earlier versions: {step: {old name: new name}}; an old name in --set, a profile,
# pipeline.yaml or a work dir's remembered params is one error naming the new one. The SD1.5 repair
# model's own settings carry ``sd15_`` (the compact model's ``compact_``): no plain name acts on one path.
_SD15_ONLY = {
    "tune": ("prompt", "rank", "alpha", "unet", "controlnet", "text_encoder", "steps", "lr", "weight_decay",
             "resolution", "precision"),
    "repair": ("t_range", "num_inference_steps", "eta", "resolution", "lpips", "guidance_scale", "precision"),
}  # fmt: skip
RENAMED_PARAMS = {step: {name: f"sd15_{name}" for name in names} for step, names in _SD15_ONLY.items()}


@dataclass(frozen=True)
class StepSpec:
    name: str
    module: str
    callable: str
    inputs: dict[str, str]  # input name -> upstream step name, or SCENE_INPUT
    outputs: tuple[str, ...]
    params: dict[str, Any]  # defaults (typed steps: every setting of the class, pipeline.yaml's values)
    description: str = ""
    params_class: type | None = None  # the step's typed params (None: untyped, the defaults give the types)
    upstream_params: dict[str, str] = field(default_factory=dict)  # field -> step whose params fill it
    optional_outputs: tuple[str, ...] = ()  # written only in some runs (go_pipeline.steps.registry)

    @property
    def function(self) -> str:
        return f"{self.module}:{self.callable}"

    @property
    def upstream(self) -> list[str]:
        return sorted({s for s in self.inputs.values() if s != SCENE_INPUT})


@dataclass
class Pipeline:
    path: Path
    steps: dict[str, StepSpec]  # in topological order
    profiles: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)

    @property
    def order(self) -> list[str]:
        return list(self.steps)

    def ancestors(self, name: str) -> set[str]:
        """Every step ``name`` depends on, transitively (not including itself)."""
        return _ancestors(self.steps, name)

    def descendants(self, name: str) -> set[str]:
        return {s for s in self.steps if name in self.ancestors(s)}

    def require_step(self, name: str, what: str, from_file: bool = True) -> StepSpec:
        """The step called ``name``; else an error about ``what`` (a pipeline.yaml entry, or with
        ``from_file=False`` a command-line argument, whose message then names no file)."""
        if name not in self.steps and name in RENAMED_STEPS and RENAMED_STEPS[name][0] in self.steps:
            new, why = RENAMED_STEPS[name]
            raise PipelineError(
                f"{what}: step {name!r} is now called {new!r} ({why}): write {new} instead of {name}",
                self.path if from_file else None,
            )
        if name not in self.steps:
            raise PipelineError(
                f"{what}: unknown step {name!r} (steps: {', '.join(self.steps)})",
                self.path if from_file else None,
            )
        return self.steps[name]

    def resolve_params(
        self, profile: str | None = None, overrides: dict[str, Any] | None = None
    ) -> dict[str, dict[str, Any]]:
        """Defaults, then the profile's overrides, then ``overrides``; each value checked (name, type, range)
        as it is applied, so an error names where the value came from.

        ``overrides``: {"step.param": value} or {step: {param: value}}. String values then have
        ``${NAME}`` / ``${NAME:-default}`` replaced from the environment, so a setting taken from the
        environment (e.g. a weights folder) is part of the cache key like any other param. A typed step's
        fields that hold another step's params are filled with that step's resolved params; its class's
        cross-field ``check()`` runs last. Returns plain JSON-able dicts (see ``step_params``)."""
        params = {name: dict(spec.params) for name, spec in self.steps.items()}
        if profile is not None:
            if profile not in self.profiles:
                known = ", ".join(self.profiles) or "none"
                raise PipelineError(f"--profile {profile}: unknown profile (profiles: {known})")
            for step, values in self.profiles[profile].items():
                for param, value in values.items():
                    params[step][param] = value  # checked at load time
        for dotted, value in flatten_overrides(overrides or {}).items():
            what = f"--set {dotted}={_show(value)}"
            step, param = self._split_dotted(dotted, what)
            params[step][param] = self._check(self.steps[step], param, value, what, None)
        resolved = {step: {k: expand_env(v) for k, v in values.items()} for step, values in params.items()}
        for name, spec in self.steps.items():
            if spec.params_class is None:
                continue
            for fname, upstream in spec.upstream_params.items():
                resolved[name][fname] = resolved[upstream]
            try:
                resolved[name] = to_mapping(from_mapping(spec.params_class, resolved[name]))
            except SettingError as e:
                raise PipelineError(f"step {name!r}: {e}") from None
        return resolved

    def _check(self, spec: StepSpec, param: str, value: Any, what: str, path: Path | None) -> Any:
        """``value`` for ``spec``'s ``param``, checked (``path``: the file it came from, None for --set)."""
        if spec.params_class is None:
            return check_param_type(spec.params[param], value, what, path)
        try:
            return check_value(spec.params_class, param, value)
        except SettingError as e:
            raise PipelineError(f"{what}: {e.problem}", path) from None

    def _split_dotted(self, dotted: str, what: str) -> tuple[str, str]:
        step, sep, param = dotted.partition(".")
        if not sep or not step or not param:
            raise PipelineError(f"{what}: expected STEP.PARAM=VALUE")
        spec = self.require_step(step, what, from_file=False)
        if param in spec.upstream_params:
            up = spec.upstream_params[param]
            raise PipelineError(
                f"{what}: {step}.{param} is step {up!r}'s params, given to {step!r}: set {up}.NAME instead"
            )
        if param not in spec.params:
            renamed_param(spec, step, param, what)
            known = ", ".join(spec.params) or "none"
            raise PipelineError(f"{what}: step {step!r} has no param {param!r} (params: {known})")
        return step, param


def ignored_overrides(
    pipeline: Pipeline, params: dict[str, dict[str, Any]], overrides: dict[str, Any]
) -> list[str]:
    """One warning line per ``--set`` value (``overrides``, flat) that the run's repair model ignores: a
    tune / repair ``sd15_*`` param when the weights step will run the compact model, or ``compact_*`` with
    sd15 (steps/registry.py ``only_model``). ``params``: the resolved params; the weights params alone decide
    the model (WeightsParams.chosen_model), so this is known at plan time. Profile values are not warned
    about: a profile is written for either model (``example`` and ``test`` set both models' values)."""
    from go_pipeline.steps.registry import WEIGHTS_STEP, only_model

    weights = next((n for n, spec in pipeline.steps.items() if spec.module == WEIGHTS_STEP), None)
    if weights is None:
        return []
    model, why = step_params(WEIGHTS_STEP, params[weights]).chosen_model()
    label = {"sd15": "SD1.5", "compact": "compact"}
    lines = []
    for dotted, value in overrides.items():
        step, _, param = dotted.partition(".")
        spec = pipeline.steps.get(step)
        needs = None if spec is None else only_model(spec.module, param)
        if needs is not None and needs != model:
            lines.append(
                f"warning: --set {dotted}={_show(value)} is ignored: it acts only on the {label[needs]} "
                f"repair model, and this run repairs with the {label[model]} model ({why})"
            )
    return lines


def renamed_param(spec: StepSpec, step: str, param: str, what: str, path: Path | None = None) -> None:
    """One PipelineError naming the new name when ``param`` is an old name of one of ``spec``'s params
    (RENAMED_PARAMS); nothing otherwise."""
    new = RENAMED_PARAMS.get(step, {}).get(param)
    if new is None or new not in spec.params:
        return
    why = " (it acts only on the SD1.5 repair model)" if new.startswith("sd15_") else ""
    old, now = f"{step}.{param}", f"{step}.{new}"
    raise PipelineError(f"{what}: {old} is now called {now}{why}: write {now} instead of {old}", path)


_ENV_REF = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}")


def expand_env(value: Any, environ: Mapping[str, str] | None = None) -> Any:
    """Replace ``${NAME}`` and ``${NAME:-default}`` in a string param (other values pass through).

    An unset ``${NAME}`` without a default becomes the empty string, as in the shell."""
    if not isinstance(value, str) or "${" not in value:
        return value
    env = os.environ if environ is None else environ
    return _ENV_REF.sub(lambda m: env.get(m.group(1)) or (m.group(2) or ""), value)


def flatten_overrides(overrides: dict[str, Any]) -> dict[str, Any]:
    """{"coarse": {"iterations": 5}} and {"coarse.iterations": 5} both become {"coarse.iterations": 5}."""
    flat: dict[str, Any] = {}
    for k, v in overrides.items():
        if "." not in k and isinstance(v, dict):
            for p, pv in v.items():
                flat[f"{k}.{p}"] = pv
        else:
            flat[k] = v
    return flat


def parse_set_argument(text: str, path: Path | str | None = None) -> tuple[str, Any]:
    """``step.param=value`` with the value parsed as YAML (so 3 is an int, 0.5 a float, [1, 2] a list)."""
    import yaml

    dotted, sep, raw = text.partition("=")
    if not sep or not dotted.strip():
        raise PipelineError(f"--set {text}: expected STEP.PARAM=VALUE", path)
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError as e:
        first = first_line(e)
        raise PipelineError(f"--set {text}: value is not valid YAML ({first})", path) from None
    return dotted.strip(), value


def _show(value: Any) -> str:
    return repr(value) if isinstance(value, str) else str(value)


def _type_name(value: Any) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "str"
    if isinstance(value, list):
        return "list"
    if isinstance(value, dict):
        return "mapping"
    if value is None:
        return "null"
    return type(value).__name__


def check_param_type(default: Any, value: Any, what: str, path: Path | str | None) -> Any:
    """``value`` converted to the default's type, or a PipelineError. An int is accepted for a float
    param (converted); a null default accepts anything; bool and int never mix."""
    if default is None:
        return value
    want, got = _type_name(default), _type_name(value)
    if want == "float" and got == "int":
        return float(value)
    if want == "float" and got == "str":  # YAML 1.1 reads 1e-3 (no dot) as a string
        try:
            value, got = float(value), "float"
        except ValueError:
            pass
    if got == "float" and not math.isfinite(value):
        raise PipelineError(f"{what}: must be a finite number", path)
    if want != got:
        raise PipelineError(f"{what}: expected {want} (default {_show(default)}), got {got}", path)
    return value


@dataclass(frozen=True)
class StepRules:
    """What the runner decides about a step without running it: its ``version`` override (in the cache
    key), the inputs whose skip skips it and the params whose emptiness skips it ({param: reason})."""

    version: str | None = None
    skip_if_skipped: tuple[str, ...] = ()
    skip_if_empty: Mapping[str, str] = field(default_factory=dict)
    skip_if_param: Mapping[str, Mapping[str, str]] = field(
        default_factory=dict
    )  # {"step.param": {value: why}}
    gate_inputs: tuple[str, ...] = ()  # inputs whose status, not content, is in the key (packaged steps)


def step_rules(spec: StepSpec, path: Path | str) -> StepRules:
    """A packaged step's rules from go_pipeline.steps.registry; a step of your own declares them at the top
    of its module (``VERSION``, ``SKIP_IF_SKIPPED``, ``SKIP_IF_EMPTY``), read with ast, without importing."""
    from go_pipeline.steps.registry import declaration

    declared = declaration(spec.module)
    if declared is not None:
        return StepRules(
            declared.version,
            declared.skip_if_skipped,
            declared.skip_if_empty,
            declared.skip_if_param,
            declared.gate_inputs,
        )
    source = _module_source(spec.module, path, spec.name)
    version = module_literal(source, "VERSION")
    if version is not None and not isinstance(version, (str, int)):
        raise PipelineError(f"step {spec.name!r}: VERSION must be a string literal", source)
    skipped = module_literal(source, "SKIP_IF_SKIPPED") or ()
    if not isinstance(skipped, tuple) or not all(isinstance(v, str) for v in skipped):
        raise PipelineError("SKIP_IF_SKIPPED must be a tuple of input names", source)
    empty = module_literal(source, "SKIP_IF_EMPTY") or {}
    if not isinstance(empty, dict) or not all(isinstance(v, str) for v in (*empty, *empty.values())):
        raise PipelineError("SKIP_IF_EMPTY must map param names to reasons", source)
    return StepRules(None if version is None else str(version), skipped, empty)


def module_literal(source: Path, name: str) -> Any:
    """The literal a module assigns to ``name`` at its top level (None when it does not), read with ast."""
    tree = ast.parse(source.read_text(encoding="utf-8"), filename=str(source))
    for node in tree.body:
        targets = (
            node.targets
            if isinstance(node, ast.Assign)
            else [node.target]
            if isinstance(node, ast.AnnAssign) and node.value is not None
            else []
        )
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            try:
                return ast.literal_eval(node.value)
            except ValueError:
                raise PipelineError(f"{name} must be a literal", source) from None
    return None


def _module_source(module: str, path: Path | str, step: str) -> Path:
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError) as e:
        raise PipelineError(f"step {step!r}: module {module!r} not found ({e})", path) from None
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        raise PipelineError(f"step {step!r}: module {module!r} not found", path)
    return Path(spec.origin)


def custom_steps_allowed(allow_custom_steps: bool | None = None) -> bool:
    """The explicit opt-in to step functions outside go_pipeline.steps: the argument, else the environment."""
    if allow_custom_steps is not None:
        return bool(allow_custom_steps)
    return os.environ.get(ALLOW_CUSTOM_STEPS_ENV, "") in ("1", "true", "yes")


def is_installed_step(module: str) -> bool:
    return module == INSTALLED_STEPS or module.startswith(INSTALLED_STEPS + ".")


def require_installed_steps(pipeline: Pipeline, allow_custom_steps: bool | None = None) -> None:
    """A pipeline file is code: each step's ``function`` is imported and called. Before anything is
    imported or located (locating a dotted module imports its parent packages), only the installed steps
    (``go_pipeline.steps.*``) pass, unless ``allow_custom_steps`` (the CLI's ``--allow-custom-steps``, or
    ``GO_ALLOW_CUSTOM_STEPS=1``). Reading a pipeline's structure (``dag``, ``params``) needs no opt-in."""
    if custom_steps_allowed(allow_custom_steps):
        return
    for spec in pipeline.steps.values():
        if not is_installed_step(spec.module):
            raise PipelineError(
                f"step {spec.name!r}: function {spec.function!r} is not an installed step "
                f"({INSTALLED_STEPS}.*); a pipeline file is code, so running functions of your own "
                f"needs --allow-custom-steps (or {ALLOW_CUSTOM_STEPS_ENV}=1)",
                pipeline.path,
            )


def load_pipeline(path: str | Path | None = None) -> Pipeline:
    """Parse and check pipeline.yaml: structure, function specs, inputs naming known steps, no cycles,
    outputs as plain relative file names, profiles naming known steps and params of the right type.
    Nothing is imported here; whoever runs or locates step code first calls ``require_installed_steps``."""
    import yaml

    from go_pipeline.resources import default_pipeline_path

    path = Path(path) if path is not None else default_pipeline_path()
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise PipelineError(f"cannot read pipeline file ({e.strerror or e})", path) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or first_line(e)
        raise PipelineError(f"invalid YAML{where}: {problem}", path) from None
    if not isinstance(data, dict):
        raise PipelineError("expected a mapping with 'steps' at the top level", path)
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise PipelineError(f"unknown top-level key(s): {', '.join(sorted(map(str, unknown)))}", path)
    if data.get("version", 1) != 1:
        raise PipelineError(f"unsupported pipeline version {data.get('version')!r} (expected 1)", path)
    raw_steps = data.get("steps")
    if not isinstance(raw_steps, dict) or not raw_steps:
        raise PipelineError("'steps' must be a non-empty mapping of step name -> step", path)

    specs = {str(name): _parse_step(str(name), body, path) for name, body in raw_steps.items()}
    for spec in specs.values():
        for input_name, upstream in spec.inputs.items():
            if upstream != SCENE_INPUT and upstream not in specs:
                raise PipelineError(
                    f"step {spec.name!r}: input {input_name!r} names unknown step {upstream!r}", path
                )
            if upstream == spec.name:
                raise PipelineError(f"step {spec.name!r}: input {input_name!r} is the step itself", path)
    order = _toposort(specs, path)
    specs = _link_upstream_params(specs, path)
    pipeline = Pipeline(path=path, steps={n: specs[n] for n in order})
    pipeline.profiles = _parse_profiles(data.get("profiles") or {}, pipeline)
    return pipeline


def _parse_step(name: str, body: Any, path: Path) -> StepSpec:
    if not name.isidentifier():
        raise PipelineError(f"step name {name!r} must be an identifier (letters, digits, _)", path)
    if not isinstance(body, dict):
        raise PipelineError(f"step {name!r}: expected a mapping with function/inputs/outputs/params", path)
    unknown = set(body) - _STEP_KEYS
    if unknown:
        raise PipelineError(f"step {name!r}: unknown key(s) {', '.join(sorted(map(str, unknown)))}", path)
    function = body.get("function")
    if not isinstance(function, str) or function.count(":") != 1:
        raise PipelineError(f"step {name!r}: function must be 'module:callable', got {function!r}", path)
    module, func = (s.strip() for s in function.split(":"))
    if not module or not func.isidentifier() or not all(p.isidentifier() for p in module.split(".")):
        raise PipelineError(f"step {name!r}: function must be 'module:callable', got {function!r}", path)
    inputs = body.get("inputs") or {}
    if not isinstance(inputs, dict) or not all(isinstance(v, str) for v in inputs.values()):
        raise PipelineError(f"step {name!r}: inputs must map input name -> step name (or '@scene')", path)
    from go_pipeline.steps.registry import declaration

    declared = declaration(module)
    catalogued = None if declared is None else [a.file for a in declared.outputs]
    if catalogued is not None and "outputs" in body and set(body["outputs"] or []) != set(catalogued):
        raise PipelineError(
            f"step {name!r}: {module} writes {', '.join(catalogued)} (go_pipeline.steps.registry); "
            "pipeline.yaml need not list them",
            path,
        )
    outputs = catalogued if catalogued is not None else body.get("outputs") or []
    if not isinstance(outputs, list) or not all(isinstance(o, str) and o for o in outputs):
        raise PipelineError(f"step {name!r}: outputs must be a list of file names", path)
    for o in outputs:
        if o.startswith("/") or ".." in Path(o).parts or o in RESERVED_OUTPUTS:
            raise PipelineError(
                f"step {name!r}: output {o!r} must be a relative file name "
                f"(not absolute, no '..', not manifest.json)",
                path,
            )
    params = body.get("params") or {}
    if not isinstance(params, dict) or not all(isinstance(k, str) for k in params):
        raise PipelineError(f"step {name!r}: params must be a mapping of name -> default", path)
    cls = params_class_for(module)
    if cls is not None:
        params = _typed_defaults(name, cls, params, path)
    return StepSpec(
        name,
        module,
        func,
        {str(k): v for k, v in inputs.items()},
        tuple(outputs),
        dict(params),
        str(body.get("description") or ""),
        params_class=cls,
        optional_outputs=() if declared is None else tuple(a.file for a in declared.sometimes),
    )


def step_params(module: str, params: dict[str, Any]) -> Any:
    """The object a step's ``run`` receives: an instance of its params class (typed steps) or the dict."""
    cls = params_class_for(module)
    return dict(params) if cls is None else from_mapping(cls, params)


def params_class_for(module: str) -> type | None:
    """The typed params class of a packaged step module (go_pipeline.steps.registry), or None."""
    from go_pipeline.steps.registry import params_class

    return params_class(module)


def _typed_defaults(step: str, cls: type, values: dict[str, Any], path: Path) -> dict[str, Any]:
    """The class's defaults with pipeline.yaml's values applied, each checked; upstream fields left out."""
    from go_pipeline.steps.registry import upstream_fields

    upstream = upstream_fields(cls)
    for key in values:
        if key in upstream:
            raise PipelineError(f"step {step!r}: param {key!r} is filled from another step's params", path)
    defaults = {k: v for k, v in to_mapping(cls()).items() if k in fields_of(cls) and k not in upstream}
    for key, value in values.items():
        if key not in defaults:
            new = RENAMED_PARAMS.get(step, {}).get(key)
            if new in defaults:
                raise PipelineError(f"step {step!r}: param {key!r} is now called {new!r}: write {new}", path)
            known = ", ".join(defaults) or "none"
            raise PipelineError(
                f"step {step!r}: {key!r} is not a setting of {cls.__name__} (settings: {known})", path
            )
        try:
            defaults[key] = to_mapping(check_value(cls, key, value))
        except SettingError as e:
            raise PipelineError(f"step {step!r}: param {e}", path) from None
    return defaults


def _link_upstream_params(specs: dict[str, StepSpec], path: Path) -> dict[str, StepSpec]:
    """Fill each typed step's ``upstream_params``: the step whose params class a field of its class holds
    (that step must be one of its ancestors, so its params are resolved first)."""
    from dataclasses import replace

    from go_pipeline.steps.registry import upstream_fields

    linked = dict(specs)
    for name, spec in specs.items():
        if spec.params_class is None:
            continue
        links = {}
        for fname, cls in upstream_fields(spec.params_class).items():
            owners = [s.name for s in specs.values() if s.params_class is cls]
            if len(owners) != 1:
                raise PipelineError(
                    f"step {name!r}: its param {fname!r} takes {cls.__name__}, which "
                    f"{'no step' if not owners else 'several steps (' + ', '.join(owners) + ')'} has",
                    path,
                )
            if owners[0] not in _ancestors(specs, name):
                raise PipelineError(
                    f"step {name!r}: its param {fname!r} takes step {owners[0]!r}'s params, "
                    f"but {owners[0]!r} is not upstream of it",
                    path,
                )
            links[fname] = owners[0]
        linked[name] = replace(spec, upstream_params=links)
    return linked


def _ancestors(specs: dict[str, StepSpec], name: str) -> set[str]:
    seen: set[str] = set()
    stack = list(specs[name].upstream)
    while stack:
        s = stack.pop()
        if s not in seen:
            seen.add(s)
            stack.extend(specs[s].upstream)
    return seen


def _toposort(specs: dict[str, StepSpec], path: Path) -> list[str]:
    """Depth-first topological order (stable: file order among independent steps); a cycle is an error
    that names the steps on it."""
    order: list[str] = []
    state: dict[str, int] = {}  # 1 = on the stack, 2 = done

    def visit(name: str, stack: list[str]) -> None:
        if state.get(name) == 2:
            return
        if state.get(name) == 1:
            cycle = stack[stack.index(name) :] + [name]
            raise PipelineError(f"cycle in step inputs: {' -> '.join(cycle)}", path)
        state[name] = 1
        stack.append(name)
        for up in specs[name].upstream:
            visit(up, stack)
        stack.pop()
        state[name] = 2
        order.append(name)

    for name in specs:
        visit(name, [])
    return order


def _parse_profiles(raw: Any, pipeline: Pipeline) -> dict[str, dict[str, dict[str, Any]]]:
    path = pipeline.path
    if not isinstance(raw, dict):
        raise PipelineError("'profiles' must map profile name -> {step: {param: value}}", path)
    profiles: dict[str, dict[str, dict[str, Any]]] = {}
    for pname, body in raw.items():
        body = body or {}
        if not isinstance(body, dict):
            raise PipelineError(f"profile {pname!r}: expected a mapping step -> {{param: value}}", path)
        resolved: dict[str, dict[str, Any]] = {}
        for step, values in flatten_and_group(body).items():
            spec = pipeline.require_step(step, f"profile {pname!r}")
            for param, value in values.items():
                if param not in spec.params:
                    renamed_param(spec, step, param, f"profile {pname!r}", path)
                    known = ", ".join(spec.params) or "none"
                    raise PipelineError(
                        f"profile {pname!r}: step {step!r} has no param {param!r} (params: {known})", path
                    )
                resolved.setdefault(step, {})[param] = to_mapping(
                    pipeline._check(spec, param, value, f"profile {pname!r}: {step}.{param}", path)
                )
        profiles[str(pname)] = resolved
    return profiles


def flatten_and_group(body: dict[str, Any]) -> dict[str, dict[str, Any]]:
    grouped: dict[str, dict[str, Any]] = {}
    for dotted, value in flatten_overrides(body).items():
        step, _, param = str(dotted).partition(".")
        grouped.setdefault(step, {})[param] = value
    return grouped
