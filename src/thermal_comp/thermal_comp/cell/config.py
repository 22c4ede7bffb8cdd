"""Machine-cell files: which nodes a cell runs, with which parameters, in which namespace.

A cell file is YAML::

    cell: cell_a                # namespace of every node of the cell (required)
    domain_id: 17               # ROS_DOMAIN_ID of the cell's processes (optional, 0..232)
    use_sim_time: true          # default for every node (optional, default false)
    production: false           # a production cell (optional, default false): every bridge node
                                # needs security_required: true, a CNC emulator node
                                # --security required and --client-trust; its processes get
                                # THERMAL_COMP_PRODUCTION=1 and refuse open access themselves
    restart:                    # default restart policy for crashed nodes (optional)
      enabled: true             #   restart a node that exits with an error or a signal
      max_restarts: 5           #   then give up on it (0..100)
      backoff_s: 1.0            #   wait before a restart, doubled on each further crash
                                #   (0.1..3600 s when enabled: no restart loop without a pause)
    env: {KEY: value}           # extra environment of the cell's processes (optional)
    nodes:                      # (required, at least one)
      - name: sensors           # node name, unique in the cell (required)
        package: thermal_sensors          # with `executable`: a console script of that package
        executable: temperature_publisher
        # or: module: thermal_sensors.temperature_publisher_node   (run as python -m MODULE)
        parameters: {period_s: 1.0}       # ROS parameters (optional)
        restart: false          # per-node override: bool or a mapping like the cell's (optional)
        args: []                # extra command-line arguments before --ros-args (optional)
        env: {KEY: value}       # extra environment of this node (optional)
        lifecycle: true         # a managed node: the launcher drives configure + activate after
                                # start, deactivate before a clean stop (optional; default: the
                                # node module declares LIFECYCLE_NODE = True)
        lifecycle_timeout_s: 30 # deadline of each transition (optional, 1..600)

Any mistake raises :class:`CellConfigError` with one line naming the file, the key path and
the bad value (also for a file that is not UTF-8 text).
"""
from __future__ import annotations

import importlib.util
import pathlib
import re
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Mapping

import yaml

from thermal_comp_common.runtime.production import PRODUCTION_ENV

NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
MODULE_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")
MAX_DOMAIN_ID = 232
_CELL_KEYS = {"cell", "domain_id", "use_sim_time", "production", "restart", "env", "nodes"}
_NODE_KEYS = {"name", "package", "executable", "module", "parameters", "restart", "args", "env",
              "lifecycle", "lifecycle_timeout_s"}
_RESTART_KEYS = {"enabled", "max_restarts", "backoff_s"}
MAX_RESTARTS = 100
MIN_BACKOFF_S = 0.1
LIFECYCLE_MARK = re.compile(r"^LIFECYCLE_NODE\s*=\s*True\b", re.M)


class CellConfigError(ValueError):
    """A cell file is invalid; the message names the file, key path and bad value."""


@dataclass(frozen=True)
class RestartPolicy:
    enabled: bool = False
    max_restarts: int = 5
    backoff_s: float = 1.0


@dataclass
class NodeSpec:
    name: str
    module: str
    parameters: dict[str, Any] = field(default_factory=dict)
    restart: RestartPolicy = RestartPolicy()
    args: list[str] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict)
    package: str | None = None
    executable: str | None = None
    lifecycle: bool = False
    lifecycle_timeout_s: float = 30.0


@dataclass
class CellConfig:
    cell: str
    nodes: list[NodeSpec]
    domain_id: int | None = None
    use_sim_time: bool = False
    env: dict[str, str] = field(default_factory=dict)
    source: str = ""
    production: bool = False

    @property
    def namespace(self) -> str:
        return "/" + self.cell


def _fail(src: str, path: str, msg: str) -> None:
    raise CellConfigError(f"{src}: {path}: {msg}")


def _restart(src: str, path: str, value: Any, default: RestartPolicy) -> RestartPolicy:
    if value is None:
        return default
    if isinstance(value, bool):
        return RestartPolicy(value, default.max_restarts, default.backoff_s)
    if not isinstance(value, Mapping):
        _fail(src, path, f"expected true/false or a mapping, got {value!r}")
    unknown = set(value) - _RESTART_KEYS
    if unknown:
        _fail(src, f"{path}.{sorted(unknown)[0]}", f"unknown key (allowed: {sorted(_RESTART_KEYS)})")
    enabled = value.get("enabled", default.enabled)
    if not isinstance(enabled, bool):
        _fail(src, f"{path}.enabled", f"expected true or false, got {enabled!r}")
    mr = value.get("max_restarts", default.max_restarts)
    if not isinstance(mr, int) or isinstance(mr, bool) or not 0 <= mr <= MAX_RESTARTS:
        _fail(src, f"{path}.max_restarts", f"expected an integer in [0, {MAX_RESTARTS}], got {mr!r}")
    bo = value.get("backoff_s", default.backoff_s)
    lo = MIN_BACKOFF_S if enabled else 0.0
    if not isinstance(bo, (int, float)) or isinstance(bo, bool) or not (lo <= bo <= 3600):
        _fail(src, f"{path}.backoff_s", f"expected seconds in [{lo:g}, 3600]"
              f"{' (a restart loop needs a pause)' if enabled else ''}, got {bo!r}")
    return RestartPolicy(enabled, mr, float(bo))


def _env(src: str, path: str, value: Any) -> dict[str, str]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        _fail(src, path, f"expected a mapping of names to values, got {value!r}")
    out = {}
    for k, v in value.items():
        if not isinstance(k, str) or not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", k):
            _fail(src, f"{path}.{k}", "not a valid environment variable name")
        if not isinstance(v, (str, int, float, bool)):
            _fail(src, f"{path}.{k}", f"expected a scalar, got {v!r}")
        out[k] = str(v)
    return out


def console_script_module(package: str, executable: str) -> str | None:
    """Module of the console script ``executable`` declared by distribution ``package``."""
    for ep in entry_points(group="console_scripts"):
        if ep.name == executable and ep.dist is not None and \
                ep.dist.name.replace("-", "_") == package.replace("-", "_"):
            return ep.value.split(":")[0]
    return None


def module_is_lifecycle(module: str) -> bool:
    """True when the node module declares ``LIFECYCLE_NODE = True`` (read, not imported)."""
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return False
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        return False
    try:
        return bool(LIFECYCLE_MARK.search(pathlib.Path(spec.origin).read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError):
        return False


def _lifecycle(src: str, p: str, n: Mapping, module: str, resolve: bool) -> tuple[bool, float]:
    lc = n.get("lifecycle")
    if lc is not None and not isinstance(lc, bool):
        _fail(src, f"{p}.lifecycle", f"expected true or false, got {lc!r}")
    if lc is None:
        lc = resolve and module_is_lifecycle(module)
    to = n.get("lifecycle_timeout_s", 30.0)
    if not isinstance(to, (int, float)) or isinstance(to, bool) or not 1 <= to <= 600:
        _fail(src, f"{p}.lifecycle_timeout_s", f"expected seconds in [1, 600], got {to!r}")
    return lc, float(to)


def _check_parameters(src: str, path: str, params: Any) -> dict[str, Any]:
    if params is None:
        return {}
    if not isinstance(params, Mapping):
        _fail(src, path, f"expected a mapping of parameter names to values, got {params!r}")

    def check(p: str, v: Any) -> None:
        if isinstance(v, Mapping):
            for k, vv in v.items():
                if not isinstance(k, str) or not NAME_RE.match(k):
                    _fail(src, f"{p}.{k}", "not a valid parameter name")
                check(f"{p}.{k}", vv)
        elif isinstance(v, list):
            kinds = {type(x) for x in v}
            if kinds - {str, int, float, bool} or (len(kinds) > 1 and kinds != {int, float}):
                _fail(src, p, f"a list parameter must hold values of one scalar type, got {v!r}")
        elif v is None or not isinstance(v, (str, int, float, bool)):
            _fail(src, p, f"expected a scalar, a list or a mapping, got {v!r}")

    for k, v in params.items():
        if not isinstance(k, str) or not NAME_RE.match(k):
            _fail(src, f"{path}.{k}", "not a valid parameter name")
        check(f"{path}.{k}", v)
    return dict(params)


def parse_cell(data: Any, source: str = "<cell>", resolve: bool = True) -> CellConfig:
    """Validate a parsed cell document. ``resolve`` checks that executables exist."""
    src = source
    if not isinstance(data, Mapping):
        _fail(src, "(top level)", f"expected a mapping with keys {sorted(_CELL_KEYS)}, got {type(data).__name__}")
    unknown = set(data) - _CELL_KEYS
    if unknown:
        _fail(src, sorted(unknown)[0], f"unknown key (allowed: {sorted(_CELL_KEYS)})")
    cell = data.get("cell")
    if not isinstance(cell, str) or not NAME_RE.match(cell):
        _fail(src, "cell", f"expected a name like 'cell_a' (letters, digits, _), got {cell!r}")
    did = data.get("domain_id")
    if did is not None and (not isinstance(did, int) or isinstance(did, bool) or not 0 <= did <= MAX_DOMAIN_ID):
        _fail(src, "domain_id", f"expected an integer in [0, {MAX_DOMAIN_ID}], got {did!r}")
    ust = data.get("use_sim_time", False)
    if not isinstance(ust, bool):
        _fail(src, "use_sim_time", f"expected true or false, got {ust!r}")
    default_restart = _restart(src, "restart", data.get("restart"), RestartPolicy())
    env = _env(src, "env", data.get("env"))
    nodes_raw = data.get("nodes")
    if not isinstance(nodes_raw, list) or not nodes_raw:
        _fail(src, "nodes", f"expected a non-empty list of nodes, got {nodes_raw!r}")
    nodes: list[NodeSpec] = []
    seen: set[str] = set()
    for i, n in enumerate(nodes_raw):
        p = f"nodes[{i}]"
        if not isinstance(n, Mapping):
            _fail(src, p, f"expected a mapping, got {n!r}")
        unknown = set(n) - _NODE_KEYS
        if unknown:
            _fail(src, f"{p}.{sorted(unknown)[0]}", f"unknown key (allowed: {sorted(_NODE_KEYS)})")
        name = n.get("name")
        if not isinstance(name, str) or not NAME_RE.match(name):
            _fail(src, f"{p}.name", f"expected a node name (letters, digits, _), got {name!r}")
        if name in seen:
            _fail(src, f"{p}.name", f"duplicate node name {name!r}")
        seen.add(name)
        module = n.get("module")
        package, executable = n.get("package"), n.get("executable")
        if module is not None:
            if not isinstance(module, str) or not MODULE_RE.match(module):
                _fail(src, f"{p}.module", f"expected a dotted module name, got {module!r}")
        else:
            if not isinstance(package, str) or not package:
                _fail(src, f"{p}.package", f"expected a package name (or give 'module'), got {package!r}")
            if not isinstance(executable, str) or not executable:
                _fail(src, f"{p}.executable", f"expected an executable of package {package!r}, got {executable!r}")
            if resolve:
                module = console_script_module(package, executable)
                if module is None:
                    _fail(src, f"{p}.executable", f"{executable!r} is not an executable of the "
                          f"installed package {package!r}")
            else:
                module = f"{package}.{executable}"
        args = n.get("args", [])
        if not isinstance(args, list) or not all(isinstance(a, str) for a in args):
            _fail(src, f"{p}.args", f"expected a list of strings, got {args!r}")
        lifecycle, lifecycle_timeout_s = _lifecycle(src, p, n, module, resolve)
        nodes.append(NodeSpec(
            name=name, module=module, lifecycle=lifecycle, lifecycle_timeout_s=lifecycle_timeout_s,
            parameters=_check_parameters(src, f"{p}.parameters", n.get("parameters")),
            restart=_restart(src, f"{p}.restart", n.get("restart"), default_restart),
            args=list(args), env=_env(src, f"{p}.env", n.get("env")),
            package=package, executable=executable))
    production = data.get("production", False)
    if not isinstance(production, bool):
        _fail(src, "production", f"expected true or false, got {production!r}")
    if production:
        _check_production(src, nodes)
        env = {**env, PRODUCTION_ENV: "1"}
    return CellConfig(cell=cell, nodes=nodes, domain_id=did, use_sim_time=ust, env=env, source=src,
                      production=production)


def _check_production(src: str, nodes: list[NodeSpec]) -> None:
    """A production cell opens no CNC to anyone: its bridges run with ``security_required`` and
    a CNC emulator in it only with ``--security required`` and a client trust list."""
    for i, n in enumerate(nodes):
        if PRODUCTION_ENV in n.env:
            _fail(src, f"nodes[{i}].env.{PRODUCTION_ENV}", "a production cell marks every process; not per node")
        if n.module.endswith("cnc_bridge_node") and n.parameters.get("security_required") is not True:
            _fail(src, f"nodes[{i}].parameters.security_required",
                  f"is {n.parameters.get('security_required')!r}: a production cell's bridge needs true")
        if n.module.startswith("cnc_bridge.cnc_emulator"):
            security = n.args[n.args.index("--security") + 1] if "--security" in n.args[:-1] else "optional"
            if security != "required" or "--client-trust" not in n.args:
                _fail(src, f"nodes[{i}].args", f"--security {security}"
                      f"{'' if '--client-trust' in n.args else ' without --client-trust'}: a production "
                      "cell's CNC needs --security required and a client trust list")


def load_cell(path: str | pathlib.Path, resolve: bool = True) -> CellConfig:
    """Read and validate a cell file."""
    path = pathlib.Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise CellConfigError(f"{path}: cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise CellConfigError(f"{path}: not a UTF-8 text file (byte {exc.object[exc.start]:#04x} "
                              f"at offset {exc.start}); a cell file is YAML text") from None
    if "\x00" in text:
        raise CellConfigError(f"{path}: a binary file (NUL bytes); a cell file is YAML text")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else "(unknown place)"
        raise CellConfigError(f"{path}: {where}: not valid YAML: "
                              f"{getattr(exc, 'problem', None) or exc}") from None
    return parse_cell(data, source=str(path), resolve=resolve)


class _QuotedStrings(yaml.SafeDumper):
    """Every string quoted: rcl's YAML parser reads unquoted Y, N, on, off ... as booleans."""


_QuotedStrings.add_representer(str, lambda d, s: d.represent_scalar("tag:yaml.org,2002:str", s, style="'"))


def parameters_file_text(cell: CellConfig, node: NodeSpec) -> str:
    """Text of the ROS 2 parameters file of one node (strings quoted, order kept)."""
    return yaml.dump(node_parameters_document(cell, node), Dumper=_QuotedStrings, sort_keys=False)


def node_parameters_document(cell: CellConfig, node: NodeSpec) -> dict:
    """The ROS 2 parameters-file document for one node of a cell."""
    params = dict(node.parameters)
    params.setdefault("use_sim_time", cell.use_sim_time)
    return {f"{cell.namespace}/{node.name}": {"ros__parameters": params}}
