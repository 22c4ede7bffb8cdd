"""`thermal-comp`: one command, subcommands contributed by every package.

Each package registers subcommands in the entry-point group ``thermal_comp.commands``
(``name = module:function``, function(argv: list[str]) -> int), so a package owns its
own command-line code and this dispatcher never needs editing. The named module is a light
command-line module (argparse and constants; the work is imported by ``function`` once the
arguments are parsed), and ``thermal-comp --help`` reads each one's summary (the first line of
its docstring) from the source without importing it: both keep the start of the command fast.
"""
from __future__ import annotations

import ast
import importlib.util
import sys
from importlib.metadata import entry_points

GROUP = "thermal_comp.commands"


def _commands() -> dict:
    return {ep.name: ep for ep in entry_points(group=GROUP)}


def _summary(ep) -> str:
    """The first line of the docstring of the entry point's module, read without running it."""
    module = ep.value.split(":")[0]
    try:
        spec = importlib.util.find_spec(module)
        source = spec.loader.get_source(module) if spec and spec.loader else None
        if source is None:
            raise ImportError(f"no source of {module}")
        doc = (ast.get_docstring(ast.parse(source)) or "").strip().splitlines()
        return doc[0] if doc else ""
    except Exception as exc:  # a broken subcommand must not break --help of the others
        return f"(unavailable: {exc.__class__.__name__}: {exc})"


def usage(commands: dict) -> str:
    lines = ["usage: thermal-comp COMMAND [ARGS...]", "",
             "Thermal-error compensation for machine tools on ROS 2 Jazzy.", "", "commands:"]
    for name in sorted(commands):
        lines.append(f"  {name:14s} {_summary(commands[name])}")
    lines += ["", "Run 'thermal-comp COMMAND --help' for the options of a command."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = _commands()
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage(commands))
        return 0
    name, rest = argv[0], argv[1:]
    if name not in commands:
        print(f"thermal-comp: unknown command '{name}'\n\n{usage(commands)}", file=sys.stderr)
        return 2
    func = commands[name].load()
    try:
        return int(func(rest) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
