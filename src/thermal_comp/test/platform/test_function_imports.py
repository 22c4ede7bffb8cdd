"""Every import inside a function says why it is not at module level.

Imports belong at the top of a module; one inside a function (or method) is kept only for a
reason - a heavy library only some calls need, an optional one, ROS kept off an import path
that must work without it - and a comment says which. The comment is on the import (on any of
its lines), or on a comment-only line right above a run of consecutive imports, which then
covers the whole run. Source modules of every package under src/ are checked, not tests.
"""
from __future__ import annotations

import ast
import io
import pathlib
import tokenize

import pytest

SRC = pathlib.Path(__file__).resolve().parents[4] / "src"
PACKAGES = sorted(p.name for p in SRC.iterdir() if (p / p.name / "__init__.py").is_file())
FUNCTIONS = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)
IMPORTS = (ast.Import, ast.ImportFrom)


def _comment_lines(source: str) -> set[int]:
    return {tok.start[0] for tok in tokenize.generate_tokens(io.StringIO(source).readline)
            if tok.type == tokenize.COMMENT}


def unexplained_imports(source: str) -> list[tuple[int, str]]:
    """(line, imported module) of every function-level import of ``source`` without a comment."""
    lines = source.splitlines()
    comments = _comment_lines(source)
    found: list[tuple[int, str]] = []

    def covered(stmt: ast.stmt, run_start: ast.stmt) -> bool:
        if comments & set(range(stmt.lineno, stmt.end_lineno + 1)):
            return True
        above = run_start.lineno - 2
        return above >= 0 and lines[above].lstrip().startswith("#")

    def visit(node: ast.AST, in_function: bool) -> None:
        for field in ("body", "orelse", "finalbody", "handlers"):
            run_start = None
            for stmt in getattr(node, field, None) or []:
                if isinstance(stmt, IMPORTS):
                    run_start = run_start or stmt
                    if in_function and not covered(stmt, run_start):
                        module = stmt.module if isinstance(stmt, ast.ImportFrom) else stmt.names[0].name
                        found.append((stmt.lineno, "." * getattr(stmt, "level", 0) + (module or "")))
                else:
                    run_start = None
                visit(stmt, in_function or isinstance(stmt, FUNCTIONS))
        if isinstance(node, (ast.Match,)):
            for case in node.cases:
                visit(case, in_function)

    visit(ast.parse(source), False)
    return found


def source_files(package: str) -> list[pathlib.Path]:
    return sorted((SRC / package / package).rglob("*.py"))


@pytest.mark.parametrize("package", PACKAGES)
def test_every_function_level_import_says_why(package):
    bad = [f"{path.relative_to(SRC)}:{line}: import {module}"
           for path in source_files(package)
           for line, module in unexplained_imports(path.read_text(encoding="utf-8"))]
    assert not bad, ("function-level imports without a comment saying why (hoist them to the top, "
                     "or add e.g. '# heavy: scikit-learn only when fitting'):\n" + "\n".join(bad))


def test_the_check_tells_explained_from_unexplained_imports():
    source = '''
import os


def plot():
    import matplotlib  # heavy: only when plotting
    import json


def fit():
    # heavy: scikit-learn only when fitting
    from sklearn import linear_model
    from sklearn import model_selection
    x = 1
    import csv


class Node:
    def start(self):
        if os.environ:
            from rclpy import node
        return [json for json in ()]
'''
    assert unexplained_imports(source) == [(7, "json"), (15, "csv"), (21, "rclpy")]


def test_every_package_is_checked():
    assert {"thermal_comp", "thermal_comp_common", "thermal_eval", "talc_model"} <= set(PACKAGES)
    assert all(source_files(p) for p in PACKAGES)
