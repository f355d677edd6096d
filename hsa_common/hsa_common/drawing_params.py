"""The drawing parameters of the nodes that draw the robot (marker_node, hsa_live): polyline
samples, backbone width, the ghost's opacity and the setpoint sphere (docs/nodes/*.md)."""

from __future__ import annotations

from hsa_common.parameters import ParamSpec
from hsa_core.model.visual import DEFAULT_POINTS

DRAWING_SPECS = (
    ParamSpec(
        "n_points",
        DEFAULT_POINTS,
        "[-] samples of the active length per backbone or rod polyline",
        low=2,
        high=200,
        read_only=True,
    ),
    ParamSpec("backbone_width", 0.002, "[m] line width of the backbone", low=0.0001, high=0.1),
    ParamSpec(
        "ghost_alpha",
        0.3,
        "[-] opacity of the ghost of the desired configuration",
        low=0.0,
        high=1.0,
    ),
    ParamSpec(
        "setpoint_diameter", 0.008, "[m] diameter of the setpoint sphere", low=0.0001, high=0.1
    ),
)
