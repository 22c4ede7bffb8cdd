"""``thermal-comp prior --machine M --out PRIOR``: a prior for TALC from the machine TYPE.

Simulates the nominal twin of ``M`` on training load programmes (never the run a prior is later
used on: other scenarios and seeds) and fits the prior's ARX models (talc_model.prior); or,
with ``--from-state``, turns the persisted TALC model of another machine into a prior. On a real
machine this costs no probing: it is simulation. docs/prior.md.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import talc_model
from talc_model.prior import PriorError, build_talc_prior, prior_from_state, save_prior, training_labels
from thermal_comp.demo_cell import MACHINES
from thermal_twin.machine_schema import load_machine
from thermal_twin.machine_spec import MachineSpecError
from thermal_twin.scenarios import make_timeline
from thermal_twin.simulate import simulate

#: Training load programmes per machine type; the LAST one is held out to choose the orders.
TRAINING_SCENARIOS = {"nmv5000": ["load-case-A", "load-case-B", "load-case-D", "talc-144h-mwf", "load-case-C"]}
#: Seeds of the training runs: 101, 102, ... (the demo's runs use seeds 0-99).
SEED_BASE = 101
#: AGP machines: training programmes of the AGP prior (the demo's lathe-random-speed is not
#: among them); the LAST one is held out for the validation RMS.
AGP_TRAINING_SCENARIOS = {"swiss_lathe": ["lathe-oil-steps", "lathe-door-openings", "lathe-test-piece"]}


def build_agp_prior_of(machine: str, config: dict, scenarios: list[str], seed_base: int = SEED_BASE,
                       progress=None) -> dict:
    """Simulate the nominal ``machine`` on ``scenarios`` and fit the AGP prior (talc_model.prior_agp)."""
    from talc_model.prior_agp import build_agp_prior
    nominal = load_machine(machine)
    recs, used = [], []
    for i, scenario in enumerate(scenarios):
        seed = seed_base + i
        recs.append(simulate(nominal, make_timeline(nominal.name, scenario, seed=seed), seed=seed).to_recording())
        used.append((scenario, seed))
        if progress:
            progress(f"simulated {scenario} (seed {seed})")
    prior = build_agp_prior(recs, config, machine=nominal.name, sources=training_labels(used))
    prior["held_out"] = training_labels(used[-1:])
    return prior


def default_config_path(machine: str) -> pathlib.Path:
    """The TALC configuration the demo ships for ``machine``."""
    m = MACHINES.get(machine, {})
    if not m.get("model_config"):
        raise PriorError(f"--machine: {machine!r} has no shipped TALC configuration; give --config")
    return pathlib.Path(talc_model.__file__).with_name("config") / m["model_config"]


def build_prior(machine: str, config: dict, scenarios: list[str], seed_base: int = SEED_BASE,
                na_max: int = 1, nb_max: int = 8, progress=None) -> dict:
    """Simulate the nominal ``machine`` on ``scenarios`` and fit the prior."""
    nominal = load_machine(machine)
    recs, used = [], []
    for i, scenario in enumerate(scenarios):
        seed = seed_base + i
        timeline = make_timeline(nominal.name, scenario, seed=seed)
        recs.append(simulate(nominal, timeline, seed=seed).to_recording())
        used.append((scenario, seed))
        if progress:
            progress(f"simulated {scenario} (seed {seed})")
    prior = build_talc_prior(recs, config, machine=nominal.name, sources=training_labels(used),
                             na_max=na_max, nb_max=nb_max)
    prior["held_out"] = training_labels(used[-1:])
    return prior


def prior_cache_dir() -> pathlib.Path:
    """Where built priors are kept: ``$THERMAL_COMP_CACHE`` or ``$XDG_CACHE_HOME/thermal-comp``
    (default ``~/.cache/thermal-comp``), sub-folder ``priors``."""
    import os
    root = os.environ.get("THERMAL_COMP_CACHE") or pathlib.Path(
        os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache") / "thermal-comp"
    return pathlib.Path(root) / "priors"


def _cache_key(machine: str, config: dict, scenarios: list[str], seed_base: int, na_max: int, nb_max: int) -> str:
    """Everything the prior depends on: the nominal preset's text, the configuration, the training
    programmes and seeds, the orders and the code that fits and runs it."""
    import hashlib
    import talc_model.prior as prior_mod
    import talc_model.talc as talc_mod
    import thermal_twin
    preset = pathlib.Path(thermal_twin.__file__).with_name("presets") / f"{machine.replace('-', '_')}.yaml"
    parts = [json.dumps({"machine": machine, "config": config, "scenarios": scenarios, "seed_base": seed_base,
                         "na_max": na_max, "nb_max": nb_max}, sort_keys=True, default=str).encode(),
             preset.read_bytes() if preset.is_file() else machine.encode(),
             pathlib.Path(prior_mod.__file__).read_bytes(), pathlib.Path(talc_mod.__file__).read_bytes()]
    h = hashlib.sha256()
    for part in parts:
        h.update(hashlib.sha256(part).digest())
    return h.hexdigest()[:16]


def cached_prior(machine: str, config: dict, scenarios: list[str], seed_base: int = SEED_BASE,
                 na_max: int = 1, nb_max: int = 8, cache_dir: pathlib.Path | None = None,
                 progress=None) -> tuple[pathlib.Path, bool]:
    """(path, built_now): the nominal type's prior from the cache, built and stored on a miss.
    A cache file that does not read back as a prior is rebuilt."""
    from talc_model.prior import load_prior
    folder = pathlib.Path(cache_dir) if cache_dir is not None else prior_cache_dir()
    path = folder / f"{machine}-{_cache_key(machine, config, scenarios, seed_base, na_max, nb_max)}.json"
    if path.is_file():
        try:
            load_prior(path)
            return path, False
        except (PriorError, OSError, ValueError):
            pass                                    # a damaged cache entry: rebuilt below
    folder.mkdir(parents=True, exist_ok=True)
    prior = build_prior(machine, config, scenarios, seed_base, na_max, nb_max, progress)
    import os
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    save_prior(tmp, prior)
    tmp.replace(path)                                # atomic: a concurrent reader never sees half a file
    return path, True


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="thermal-comp prior", description=__doc__.split("\n\n")[0])
    ap.add_argument("--machine", default="nmv5000", help="the NOMINAL machine type (preset name or YAML)")
    ap.add_argument("--out", required=True, help="prior file to write (JSON)")
    ap.add_argument("--config", help="TALC configuration YAML (default: the one the demo ships for the machine)")
    ap.add_argument("--scenarios", help="comma-separated training scenarios, the last held out "
                                        "(default for nmv5000: " + ",".join(TRAINING_SCENARIOS["nmv5000"]) + ")")
    ap.add_argument("--seed-base", type=int, default=SEED_BASE, help="seed of the first training run (default %(default)s)")
    ap.add_argument("--na-max", type=int, default=1, help="largest n_a of the prior (default %(default)s)")
    ap.add_argument("--nb-max", type=int, default=8, help="largest n_b of the prior (default %(default)s)")
    ap.add_argument("--from-state", metavar="STATE",
                    help="instead: the persisted TALC model state (model_state.json) of another machine")
    return ap


def main(argv: list[str] | None = None) -> int:
    a = _parser().parse_args(argv)
    import yaml
    t0 = time.perf_counter()
    try:
        if a.from_state:
            try:
                state = json.loads(pathlib.Path(a.from_state).read_text())
            except (OSError, json.JSONDecodeError) as exc:
                raise PriorError(f"--from-state {a.from_state!r}: cannot read it ({exc})") from None
            if isinstance(state, dict) and state.get("kind") == "agp":   # another lathe's persisted AGP
                from talc_model.prior_agp import agp_prior_from_state
                prior = agp_prior_from_state(state, machine=a.machine)
            else:
                prior = prior_from_state(state, machine=a.machine)
        elif load_machine(a.machine).name in AGP_TRAINING_SCENARIOS:
            return _main_agp(a, t0)
        else:
            cfg_path = pathlib.Path(a.config) if a.config else default_config_path(a.machine)
            config = yaml.safe_load(cfg_path.read_text()) or {}
            name = load_machine(a.machine).name
            scenarios = a.scenarios.split(",") if a.scenarios else TRAINING_SCENARIOS.get(name)
            if not scenarios:
                raise PriorError(f"--scenarios: no default training scenarios for machine {name!r}")
            prior = build_prior(a.machine, config, [s.strip() for s in scenarios], a.seed_base,
                                a.na_max, a.nb_max, progress=lambda m: print(m, file=sys.stderr))
    except (PriorError, MachineSpecError, ValueError, OSError) as exc:
        print(f"thermal-comp prior: {exc}", file=sys.stderr)
        return 2
    path = save_prior(a.out, prior)
    orders = {c: (m["orders"]["na"], m["orders"]["nb"]) for c, m in prior["talc_state"]["models"].items()}
    print(f"wrote {path} ({time.perf_counter() - t0:.1f} s): TALC prior of {prior['machine']} from "
          f"{', '.join(prior['sources'])}")
    for c, (na, nb) in orders.items():
        v = prior["validation_rms"].get(c)
        print(f"  {c}: n_a {na}, n_b {nb}, held-out simulation RMS {v:.2f}" if v == v else f"  {c}: n_a {na}, n_b {nb}")
    return 0


def _main_agp(a, t0: float) -> int:
    """``thermal-comp prior --machine swiss-lathe``: the AGP prior of the nominal lathe."""
    import yaml
    config = (yaml.safe_load(pathlib.Path(a.config).read_text()) or {}) if a.config else {}
    name = load_machine(a.machine).name
    scenarios = [s.strip() for s in a.scenarios.split(",")] if a.scenarios else AGP_TRAINING_SCENARIOS[name]
    try:
        prior = build_agp_prior_of(a.machine, config, scenarios, a.seed_base,
                                   progress=lambda m: print(m, file=sys.stderr))
    except (PriorError, MachineSpecError, ValueError, OSError) as exc:
        print(f"thermal-comp prior: {exc}", file=sys.stderr)
        return 2
    path = save_prior(a.out, prior)
    print(f"wrote {path} ({time.perf_counter() - t0:.1f} s): AGP prior of {prior['machine']} from "
          f"{', '.join(prior['sources'])}; inputs {', '.join(prior['input_names'])}")
    for c, v in prior["validation_rms"].items():
        print(f"  {c}: {prior['training_points']} training points, held-out RMS {v:.2f} um")
    return 0


if __name__ == "__main__":
    sys.exit(main())
