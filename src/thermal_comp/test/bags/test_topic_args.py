"""Topic arguments of the recorder: known topics by name, others with their type."""
import pytest

from thermal_comp.bags.recorder_node import DEFAULT_TOPICS, parse_topic_arg, starts_with_stamp


def test_known_topics_relative_and_in_a_namespace():
    assert parse_topic_arg("temperatures")[:2] == ("temperatures", "thermal_comp_msgs/msg/TemperatureArray")
    assert parse_topic_arg("/cell1/errors/predicted")[:2] == ("/cell1/errors/predicted",
                                                              "thermal_comp_msgs/msg/ThermalErrors")
    assert parse_topic_arg("/clock")[:2] == ("/clock", "rosgraph_msgs/msg/Clock")


def test_other_topics_need_a_type():
    assert parse_topic_arg("/diag:std_msgs/String")[:2] == ("/diag", "std_msgs/msg/String")
    with pytest.raises(ValueError, match="'/diag' is not a known topic; give its type as '/diag:pkg/msg/Type'"):
        parse_topic_arg("/diag")
    with pytest.raises(ValueError, match="has no topic name"):
        parse_topic_arg(":std_msgs/String")


def test_every_default_type_starts_with_a_stamp():
    # the recorder's header-stamp timestamps rely on it
    assert all(starts_with_stamp(t) for t, _ in DEFAULT_TOPICS.values())
    assert not starts_with_stamp("std_msgs/msg/String")
