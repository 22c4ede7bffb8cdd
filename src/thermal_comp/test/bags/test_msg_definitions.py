"""Schema texts and type hashes of our message types."""
import pytest

from thermal_comp_common.bags import msg_definitions as md
def test_every_own_type_is_found():
    types = md.own_message_types()
    assert "thermal_comp_msgs/msg/TemperatureArray" in types
    assert len(types) == 6


@pytest.mark.parametrize("type_name", md.own_message_types() + ["rosgraph_msgs/msg/Clock",
                                                                "std_msgs/msg/Header"])
def test_rihs01_hash_equals_the_one_rosidl_generated(type_name):
    installed = md.installed_type_hash(type_name)
    assert installed and installed.startswith("RIHS01_")
    assert md.type_hash(type_name) == installed


def test_schema_text_has_each_dependency_once_after_the_type():
    text = md.schema_text("thermal_comp_msgs/ModelStatus")
    assert text.startswith(md.msg_text("thermal_comp_msgs/msg/ModelStatus").rstrip("\n"))
    assert text.count("MSG: std_msgs/Header\n") == 1
    assert text.count("MSG: builtin_interfaces/Time\n") == 1
    assert text.count(md.SEPARATOR) == 2
    assert text.index("MSG: std_msgs/Header") < text.index("MSG: builtin_interfaces/Time")


def test_field_types_skip_constants():
    assert md.field_types("thermal_comp_msgs/msg/TemperatureArray") == [
        "std_msgs/msg/Header", "string", "float64", "uint8"]
    assert md.first_field_type("rosgraph_msgs/msg/Clock") == "builtin_interfaces/msg/Time"


@pytest.mark.parametrize("bad", ["TemperatureArray", "a/b/c/d", "pkg/srv/X", ""])
def test_bad_type_names_are_named_in_the_error(bad):
    with pytest.raises(md.MsgDefinitionError, match="message type"):
        md.normalize_type(bad)


def test_unknown_type_names_the_type():
    with pytest.raises(md.MsgDefinitionError, match="NoSuchType"):
        md.msg_text("thermal_comp_msgs/msg/NoSuchType")


@pytest.mark.ros
def test_rihs01_hash_equals_the_one_the_running_typesupport_announces(ros_context):
    """The middleware's own type hash (from the compiled typesupport) of each of our types."""
    import rclpy
    from thermal_comp.bags.recorder_node import message_class
    node = rclpy.create_node("hash_probe", context=ros_context)
    try:
        for i, t in enumerate(md.own_message_types() + ["rosgraph_msgs/msg/Clock"]):
            node.create_publisher(message_class(t), f"hash_probe_{i}", 1)
            info = node.get_publishers_info_by_topic(f"/hash_probe_{i}")
            assert len(info) == 1
            assert str(info[0].topic_type_hash) == md.type_hash(t), t
    finally:
        node.destroy_node()
