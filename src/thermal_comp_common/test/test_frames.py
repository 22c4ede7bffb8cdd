"""The frame tree of a machine description: root, bodies, sensors at their position."""
import math
import random

import pytest

from thermal_comp_common.frames import (MACHINE_BASE_FRAME, FrameError, FrameTransform, frame_tree,
                                        positions_in_root)

DESC = {
    "nodes": {"table": {"capacity": 1.0, "position_mm": [0, 0, 200]}, "column": {"capacity": 2.0}},
    "sensors": {
        "t_table": {"of": "table", "position_mm": [100, 0, 250]},
        "ambient": {"of": "ambient", "position_mm": [-1800, 0, 1500]},      # a boundary, not a body
        "delta": {"of": {"table": 1.0, "column": -1.0}, "position_mm": [0, 0, -450]},
        "unplaced": {"of": "column"},
    },
}


def test_tree_has_root_bodies_and_placed_sensors():
    tree = frame_tree(DESC)
    by_child = {t.child: t for t in tree}
    assert by_child["body_table"] == FrameTransform(MACHINE_BASE_FRAME, "body_table", (0.0, 0.0, 0.2))
    assert by_child["body_column"].translation_m == (0.0, 0.0, 0.0)
    # a sensor on a body hangs from it, relative to the body's origin
    assert by_child["sensor_t_table"].parent == "body_table"
    assert by_child["sensor_t_table"].translation_m == pytest.approx((0.1, 0.0, 0.05))
    # boundaries and combinations hang from the root
    assert by_child["sensor_ambient"].parent == MACHINE_BASE_FRAME
    assert by_child["sensor_delta"].parent == MACHINE_BASE_FRAME
    assert "sensor_unplaced" not in by_child
    # parents come first
    seen = {MACHINE_BASE_FRAME}
    for t in tree:
        assert t.parent in seen
        seen.add(t.child)


def test_every_sensor_lands_at_its_position_mm_in_the_root():
    rng = random.Random(7)
    for _ in range(50):
        nodes = {f"n{i}": ({"position_mm": [rng.uniform(-2e3, 2e3) for _ in range(3)]} if rng.random() < 0.5 else {})
                 for i in range(rng.randint(1, 6))}
        sensors = {f"s{j}": {"of": rng.choice(list(nodes) + ["ambient"]),
                             "position_mm": [rng.uniform(-2e3, 2e3) for _ in range(3)]}
                   for j in range(rng.randint(1, 8))}
        pos = positions_in_root(frame_tree({"nodes": nodes, "sensors": sensors}, prefix="cell_a/"))
        assert pos["cell_a/machine_base"] == (0.0, 0.0, 0.0)
        for sid, spec in sensors.items():
            assert pos[f"cell_a/sensor_{sid}"] == pytest.approx(tuple(v / 1000 for v in spec["position_mm"]))


def test_rotations_compose():
    quarter_z = (0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4))
    tree = [FrameTransform("machine_base", "a", (1.0, 0.0, 0.0), quarter_z),
            FrameTransform("a", "b", (1.0, 0.0, 0.0))]
    assert positions_in_root(tree)["b"] == pytest.approx((1.0, 1.0, 0.0))


@pytest.mark.parametrize("desc, field", [
    ({"sensors": {"s": {"position_mm": [1, 2]}}}, "sensors.s.position_mm"),
    ({"sensors": {"s": {"position_mm": [1, 2, float("nan")]}}}, "sensors.s.position_mm"),
    ({"nodes": {"n": {"position_mm": "x"}}}, "nodes.n.position_mm"),
    ({"sensors": [1, 2]}, "sensors"),
    ([], "description"),
])
def test_bad_descriptions_name_the_field(desc, field):
    with pytest.raises(FrameError, match=field.replace(".", r"\.")):
        frame_tree(desc)


def test_bad_prefix_and_broken_trees_are_refused():
    with pytest.raises(FrameError, match="prefix"):
        frame_tree(DESC, prefix="/cell")
    with pytest.raises(FrameError, match="defined twice"):
        positions_in_root([FrameTransform("r", "a", (0, 0, 0)), FrameTransform("r", "a", (1, 0, 0))])
    with pytest.raises(FrameError, match="more than one root"):
        positions_in_root([FrameTransform("r", "a", (0, 0, 0)), FrameTransform("q", "b", (1, 0, 0))])
