"""The machine-type priors behind ``thermal-comp prior`` (:mod:`thermal_comp.prior.cli` parses the
arguments) and the demo's default prior: simulate the nominal twin of a machine on its training
load programmes (:mod:`thermal_comp.prior.programmes`) and fit the prior of the model (TALC:
talc_model.prior.talc, AGP: prior_agp, characteristic diagrams: prior_cd), kept in a cache keyed
by everything it depends on; or turn the persisted model of another machine into a prior.
docs/prior.md.
"""
from __future__ import annotations

import glob
import hashlib
import importlib
import json
import os
import pathlib
import sys
import time

import talc_model
import thermal_twin
import yaml
from talc_model.model_persistence import FORMAT as STATE_FORMAT, ModelStateError, read_state
from talc_model.prior.agp import agp_prior_from_state, build_agp_prior
from talc_model.prior.cd import build_cd_prior, cd_prior_from_state
from talc_model.prior.common import PriorError
from talc_model.prior.history import build_history_prior
from talc_model.prior.integrity import check_prior
from talc_model.prior.talc import build_talc_prior, load_prior, prior_from_state, save_prior, training_labels
from thermal_comp.demo.cell import MACHINES
from thermal_comp.prior.programmes import SEED_BASE, TRAINING_SCENARIOS
from thermal_comp_common.bags.recording import load_recording
from thermal_twin.identify.own_config import own_model_config
from thermal_twin.machine.schema import load_machine
from thermal_twin.machine.spec import MachineSpecError
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

#: the modules each kind's prior is fitted and run by (their source is part of the cache key)
PRIOR_MODULES = {"talc": ["talc_model.prior.talc", "talc_model.prior.integrity", "talc_model.talc.model",
                          "talc_model.type_inputs", "thermal_twin.sim.type_soft_sensors"],
                 "agp": ["talc_model.prior.agp", "talc_model.prior.integrity", "talc_model.agp.model",
                         "talc_model.agp.gaussian_process"],
                 "cd": ["talc_model.prior.cd", "talc_model.prior.integrity", "talc_model.cd.model", "talc_model.cd.diagram",
                        "talc_model.cd.input_selection", "talc_model.probing.uncertainty_weighted_hold",
                        "talc_model.type_inputs", "thermal_twin.sim.type_soft_sensors"]}


def type_name(machine: str) -> str:
    """The twin's name of a machine (``swiss-lathe`` -> ``swiss_lathe``)."""
    return load_machine(machine).name


def default_model_kind(machine: str) -> str:
    """The model the demo runs on ``machine`` (MACHINES), else TALC."""
    name = type_name(machine)
    return next((m["model_kind"] for k, m in MACHINES.items() if k.replace("-", "_") == name), "talc")


def training_scenarios(kind: str, machine: str) -> list[str] | None:
    """The default training programmes of ``kind``'s prior for ``machine`` (None: there are none)."""
    return TRAINING_SCENARIOS.get(kind, {}).get(type_name(machine))


def default_config(machine: str, kind: str) -> dict:
    """The model configuration the demo runs ``machine`` with: TALC's shipped YAML; the AGP's
    and CD's defaults ({}), as the model node uses them without a ``model_config``. ``machine``
    a twin YAML (a unit's twin): the configuration beside it that names it (``model_config.yaml``
    of ``twin init`` or ``learn``), else its type's with that file as the soft-sensor twin
    (``type_model``), so the prior and the run read the twin they were given."""
    if kind != "talc":
        return {}
    own = own_model_config(machine) if is_twin_file(machine) else None
    if own is not None:      # twin init's folder: the twin's own configuration, not a namesake preset's
        return own
    config = yaml.safe_load(default_config_path(machine).read_text()) or {}
    if is_twin_file(machine) and config.get("type_model"):
        config["type_model"] = str(pathlib.Path(machine).resolve())
    return config


def is_twin_file(machine: str) -> bool:
    """``machine`` names a twin YAML file rather than a preset."""
    return pathlib.Path(machine).suffix in (".yaml", ".yml") and pathlib.Path(machine).is_file()


def default_config_path(machine: str) -> pathlib.Path:
    """The TALC configuration the demo ships for ``machine`` (a twin file: for its type)."""
    if is_twin_file(machine):
        machine = type_name(machine).replace("_", "-") if type_name(machine).replace("_", "-") in MACHINES \
            else type_name(machine)
    m = MACHINES.get(machine, {})
    if not m.get("model_config"):
        raise PriorError(f"--machine: {machine!r} has no shipped TALC configuration; give --config")
    return pathlib.Path(talc_model.__file__).with_name("config") / m["model_config"]


def build_prior(machine: str, config: dict, scenarios: list[str], seed_base: int = SEED_BASE,
                na_max: int = 1, nb_max: int = 8, progress=None, kind: str = "talc") -> dict:
    """Simulate the nominal ``machine`` on ``scenarios`` (seeds ``seed_base``, +1, ...) and fit
    the prior of ``kind`` (``na_max`` / ``nb_max``: TALC's orders)."""
    if kind not in TRAINING_SCENARIOS:
        raise PriorError(f"--model: {kind!r} has no prior (one of {sorted(TRAINING_SCENARIOS)})")
    nominal = load_machine(machine)
    recs, used = [], []
    for i, scenario in enumerate(scenarios):
        seed = seed_base + i
        recs.append(simulate(nominal, make_timeline(nominal.name, scenario, seed=seed), seed=seed).to_recording())
        used.append((scenario, seed))
        if progress:
            progress(f"simulated {scenario} (seed {seed})")
    sources = training_labels(used)
    if kind == "talc":
        prior = build_talc_prior(recs, config, machine=nominal.name, sources=sources, na_max=na_max, nb_max=nb_max)
    elif kind == "agp":
        prior = build_agp_prior(recs, config, machine=nominal.name, sources=sources)
    else:
        prior = build_cd_prior(recs, config, machine=nominal.name, sources=sources)
    prior["held_out"] = training_labels(used[-1:])
    return prior


def prior_cache_dir() -> pathlib.Path:
    """Where built priors are kept: ``$THERMAL_COMP_CACHE`` or ``$XDG_CACHE_HOME/thermal-comp``
    (default ``~/.cache/thermal-comp``), sub-folder ``priors``."""
    root = os.environ.get("THERMAL_COMP_CACHE") or pathlib.Path(
        os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache") / "thermal-comp"
    return pathlib.Path(root) / "priors"


def _cache_key(machine: str, config: dict, scenarios: list[str], seed_base: int, na_max: int, nb_max: int,
               kind: str = "talc") -> str:
    """Everything the prior depends on: the model kind, the nominal preset's text, the
    configuration, the training programmes and seeds, the orders and the code that fits and runs it."""
    preset = pathlib.Path(thermal_twin.__file__).with_name("presets") / f"{machine.replace('-', '_')}.yaml"
    parts = [json.dumps({"machine": machine, "config": config, "scenarios": scenarios, "seed_base": seed_base,
                         "na_max": na_max, "nb_max": nb_max, "kind": kind}, sort_keys=True, default=str).encode(),
             preset.read_bytes() if preset.is_file() else
             pathlib.Path(machine).read_bytes() if is_twin_file(machine) else machine.encode()]
    parts += [pathlib.Path(importlib.import_module(m).__file__).read_bytes() for m in PRIOR_MODULES[kind]]
    type_yaml = pathlib.Path(str(config.get("type_model") or ""))    # TALC's soft sensors from a type's YAML
    parts += [type_yaml.read_bytes()] if type_yaml.suffix in (".yaml", ".yml") and type_yaml.is_file() else []
    h = hashlib.sha256()
    for part in parts:
        h.update(hashlib.sha256(part).digest())
    return h.hexdigest()[:16]


def cached_prior(machine: str, config: dict, scenarios: list[str], seed_base: int = SEED_BASE,
                 na_max: int = 1, nb_max: int = 8, cache_dir: pathlib.Path | None = None,
                 progress=None, kind: str = "talc") -> tuple[pathlib.Path, bool]:
    """(path, built_now): the nominal type's prior of ``kind`` from the cache, built and stored
    on a miss. The key hashes the inputs, not the file: a cache file that fails its content hash,
    identity or checks (talc_model.prior.integrity), or is of another kind, is rebuilt with a
    warning on stderr."""
    folder = pathlib.Path(cache_dir) if cache_dir is not None else prior_cache_dir()
    key = _cache_key(machine, config, scenarios, seed_base, na_max, nb_max, kind)
    label = type_name(machine) if is_twin_file(machine) else machine    # a file's path is no file name
    path = folder / f"{label}-{kind}-{key}.json"
    if path.is_file():
        try:
            cached = load_prior(path)
            if cached.get("model_kind", "talc") != kind or cached.get("machine") not in (machine, type_name(machine)):
                raise PriorError(f"prior {str(path)!r}: identity is {cached.get('model_kind', 'talc')!r} of "
                                 f"{cached.get('machine')!r}, expected {kind!r} of {type_name(machine)!r}")
            check_prior(cached)
            return path, False
        except (PriorError, OSError, ValueError) as exc:
            print(f"warning: prior cache: {exc}; rebuilding it", file=sys.stderr)
    folder.mkdir(parents=True, exist_ok=True)
    prior = build_prior(machine, config, scenarios, seed_base, na_max, nb_max, progress, kind=kind)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    save_prior(tmp, prior)
    tmp.replace(path)                                # atomic: a concurrent reader never sees half a file
    return path, True


def _from_state(a) -> dict:
    try:
        state = json.loads(pathlib.Path(a.from_state).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise PriorError(f"--from-state {a.from_state!r}: cannot read it ({exc})") from None
    if isinstance(state, dict) and state.get("format") == STATE_FORMAT:     # a node's saved state file
        try:
            state = read_state(a.from_state)["state"]                        # its hash checked
        except ModelStateError as exc:
            raise PriorError(f"--from-state {exc}") from None
    if isinstance(state, dict) and state.get("kind") == "agp":   # another lathe's persisted AGP
        return agp_prior_from_state(state, machine=a.machine)
    if isinstance(state, dict) and state.get("kind") == "cd":     # another machine's persisted CD model
        return cd_prior_from_state(state, machine=a.machine, sensors=load_machine(a.machine).sensor_ids)
    return prior_from_state(state, machine=a.machine)


#: the machine type of a twin prior when --machine is not given
DEFAULT_MACHINE = "nmv5000"


def recording_paths(runs: str) -> list[pathlib.Path]:
    """The recordings ``runs`` names (comma-separated files, bag folders, folders of recordings,
    globs), in the order given (a folder's and a glob's matches sorted by name)."""
    out: list[pathlib.Path] = []
    for item in (x.strip() for x in runs.split(",")):
        if not item:
            continue
        p = pathlib.Path(item)
        if any(ch in item for ch in "*?["):
            found = [pathlib.Path(m) for m in sorted(glob.glob(item))]
            if not found:
                raise PriorError(f"--from-recordings: {item!r} matches no file")
            out += found
        elif p.is_dir() and not (p / "metadata.yaml").is_file():     # a folder of recordings, not a bag
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in (".csv", ".mcap")
                           or (q / "metadata.yaml").is_file())
            if not found:
                raise PriorError(f"--from-recordings: folder {item!r} holds no .csv, .mcap or bag folder")
            out += found
        elif p.exists():
            out.append(p)
        else:
            raise PriorError(f"--from-recordings: {item!r}: no such file or folder")
    if not out:
        raise PriorError(f"--from-recordings: {runs!r} names no recording")
    return out


def _from_recordings(a) -> dict:
    """The history prior of ``a.model`` (default TALC) from the runs ``a.from_recordings`` names."""
    paths = recording_paths(a.from_recordings)
    recs = []
    for p in paths:
        try:
            recs.append(load_recording(p, sample_period_s=a.sample_period_s))
        except (OSError, ValueError) as exc:
            raise PriorError(f"--from-recordings: {exc}") from None
        print(f"read {p} ({len(recs[-1])} rows)", file=sys.stderr)
    overrides = (yaml.safe_load(pathlib.Path(a.config).read_text()) or {}) if a.config else {}
    fit = {"na_max": a.na_max, "nb_max": a.nb_max} if (a.model or "talc") == "talc" else {}
    return build_history_prior(a.model or "talc", recs, overrides, machine=a.machine or "",
                               sources=[str(p) for p in paths], **fit)


def _describe(prior: dict) -> list[str]:
    """What ``thermal-comp prior`` prints about the prior it wrote."""
    kind = prior.get("model_kind", "talc")
    val = prior.get("validation_rms", {})
    if kind == "talc":
        return [f"  {c}: n_a {m['orders']['na']}, n_b {m['orders']['nb']}"
                + (f", held-out simulation RMS {val[c]:.2f}" if val.get(c) == val.get(c) and c in val else "")
                for c, m in prior["talc_state"]["models"].items()]
    if kind == "agp":
        return [f"  {c}: {prior['training_points']} training points, held-out RMS {v:.2f} um" for c, v in val.items()]
    return [f"  {c}: inputs {', '.join(prior['input_names'][c])}, held-out RMS {v:.2f}" for c, v in val.items()]


def run(a) -> int:
    """Build or convert the prior the parsed arguments ask for and write it; the exit code (0 written,
    2 bad arguments or input)."""
    t0 = time.perf_counter()
    try:
        if a.from_recordings:
            prior = _from_recordings(a)
        elif a.from_state:
            a.machine = a.machine or DEFAULT_MACHINE
            prior = _from_state(a)
        else:
            a.machine = a.machine or DEFAULT_MACHINE
            kind = a.model or default_model_kind(a.machine)
            config = ((yaml.safe_load(pathlib.Path(a.config).read_text()) or {}) if a.config
                      else default_config(a.machine, kind))
            twin_file = str(pathlib.Path(a.machine).resolve()) if is_twin_file(a.machine) else None
            if twin_file and config.get("type_model") and config["type_model"] != twin_file:
                print(f"prior: soft-sensor twin 'type_model' {config['type_model']!r} -> {twin_file!r} "
                      "(the twin of --machine)", file=sys.stderr)
                config["type_model"] = twin_file
            scenarios = a.scenarios.split(",") if a.scenarios else training_scenarios(kind, a.machine)
            if not scenarios:
                raise PriorError(f"--scenarios: no default training scenarios for a {kind} prior of "
                                 f"{type_name(a.machine)!r}")
            prior = build_prior(a.machine, config, [s.strip() for s in scenarios], a.seed_base, a.na_max,
                                a.nb_max, progress=lambda m: print(m, file=sys.stderr), kind=kind)
    except (PriorError, MachineSpecError, ValueError, OSError) as exc:
        print(f"thermal-comp prior: {exc}", file=sys.stderr)
        return 2
    path = save_prior(a.out, prior)
    print(f"wrote {path} ({time.perf_counter() - t0:.1f} s): {prior.get('model_kind', 'talc').upper()} prior of "
          f"{prior['machine']} from {', '.join(prior['sources'])}"
          + (f" (history; held out: {prior['held_out'][0]})" if prior.get("prior_source") else ""))
    print("\n".join(_describe(prior)))
    return 0
