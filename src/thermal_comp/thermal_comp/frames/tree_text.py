"""The frame tree as indented text (the work of ``thermal-comp frames``)."""
from __future__ import annotations

import sys

from thermal_comp.frames.description import load_description
from thermal_comp_common.frames import FrameError, FrameTransform, frame_tree, positions_in_root


def tree_lines(transforms: list[FrameTransform]) -> list[str]:
    """One line per frame, children indented under their parent, in the list's order."""
    children: dict[str, list[FrameTransform]] = {}
    for t in transforms:
        children.setdefault(t.parent, []).append(t)
    pos = positions_in_root(transforms)
    roots = [p for p in children if p not in {t.child for t in transforms}]
    lines: list[str] = []

    def walk(frame: str, depth: int) -> None:
        for t in children.get(frame, []):
            rel = ", ".join(f"{v:+.3f}" for v in t.translation_m)
            absolute = ", ".join(f"{v:+.3f}" for v in pos[t.child])
            lines.append(f"{'  ' * depth}{t.child:<{32 - 2 * depth}} from parent [{rel}]  in root [{absolute}]")
            walk(t.child, depth + 1)

    for r in roots:
        lines.append(r)
        walk(r, 1)
    return lines


def run(args) -> int:
    try:
        transforms = frame_tree(load_description(args.machine), prefix=args.prefix)
    except FrameError as exc:
        print(f"thermal-comp frames: {exc}", file=sys.stderr)
        return 2
    print("\n".join(tree_lines(transforms)))
    return 0
