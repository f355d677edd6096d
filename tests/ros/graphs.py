"""Graph set-ups shared by the ROS tests: node groups started together (they compile in
parallel), each stopped cleanly (exit 0) at the end of its test module."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

from tests.ros.faults import NodeProcess, start_all

DIAGNOSTICS_5HZ = ("-p", "diagnostics_period:=0.2")


def stop_all(procs: dict[str, NodeProcess]) -> None:
    """Stop every node; each must exit 0."""
    assert {key: proc.stop() for key, proc in procs.items()} == dict.fromkeys(procs, 0)


def estimation_graph(
    ns: str,
    controller: Sequence[str] = (),
    input_depth: int = 0,
    **more: tuple[str, Sequence[str]],
) -> Iterator[dict[str, NodeProcess]]:
    """mocap_bridge (platform poses on ``<ns>/mocap/platform/pose``), kinematics_node and
    controller_node (FPU, P-satI-D, no driver in the graph, ``controller`` arguments added) in
    ``ns``, diagnostics at 5 Hz, and the ``more`` nodes (key: executable, arguments); a module
    fixture yields from it. ``input_depth`` > 0 deepens the pipeline's best-effort inputs (pose,
    ee_pose, state) to that many samples through their QoS overrides, so that a node that stalls
    on a loaded machine drops none of what a test counts (default: the nodes' own depth, 5)."""
    common = ["-r", f"__ns:={ns}", *DIAGNOSTICS_5HZ]

    def deep(topic: str) -> list[str]:
        if not input_depth:
            return []
        return ["-p", f"qos_overrides.{ns}/{topic}.subscription.depth:={input_depth}"]

    pose = "mocap/platform/pose"
    procs = start_all(
        {
            "bridge": (
                "mocap_bridge",
                [*common, "-p", f"platform_topic:={ns}/{pose}", *deep(pose)],
            ),
            "kinematics": ("kinematics_node", [*common, *deep("ee_pose")]),
            "controller": (
                "controller_node",
                [*common, "-p", "driver_timeout:=0.0", *deep("state"), *controller],
            ),
            **more,
        }
    )
    yield procs
    stop_all(procs)


def controller_alone(ns: str) -> Iterator[NodeProcess]:
    """controller_node (FPU, P-satI-D, 40 Hz) in ``ns`` without a driver, diagnostics at 5 Hz;
    a module fixture yields from it."""
    procs = start_all(
        {
            "controller": (
                "controller_node",
                ["-r", f"__ns:={ns}", *DIAGNOSTICS_5HZ, "-p", "driver_timeout:=0.0"],
            )
        }
    )
    yield procs["controller"]
    stop_all(procs)
