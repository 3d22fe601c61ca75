"""The node reference, docs/nodes.md, generated from the nodes themselves.

Each node class is built in-process with its default parameters (no spinning, no bag played) and read back:
parameters (name, type, default, description from the ParameterDescriptor), publishers, subscriptions and
services with their types and QoS. Defaults are cheap: tracking's split backend, local_mapping and
loop_closing load their config and vocabulary in under a second; detection is configured and activated (it
subscribes to images only once its ONNX model is loaded, about a second); bag_player opens the bundled sample bag. Tracking is built again with
overrides (`NodeSpec.variants`: compressed, ack_topic, movers, in-process backend, slam:=false, ...) because
some topics exist only with them (the map resync topics only with the split backend); those rows say when.
The hand-written text of each section comes from docs/nodes_intro/<node>.md, so regenerating keeps it.

    python tools/gen_node_reference.py           # rewrite docs/nodes.md
    python tools/gen_node_reference.py --check   # exit 1 when docs/nodes.md is out of date
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from collections.abc import Set as AbstractSet
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from changing_slam_ros.nodes.node_help import format_value

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "nodes.md"
INTROS = REPO / "docs" / "nodes_intro"
SAMPLE_BAG = REPO / "bags" / "tum_fr1_xyz_first10.mcap"

# What rclpy gives every node (and every lifecycle node); listed once in the page's header, not per node.
STANDARD_PARAMETERS = {"use_sim_time", "start_type_description_service"}
STANDARD_SERVICES = {"describe_parameters", "get_parameters", "get_parameter_types", "list_parameters",
                     "set_parameters", "set_parameters_atomically", "get_type_description", "change_state",
                     "get_state", "get_available_states", "get_available_transitions", "get_transition_graph"}
STANDARD_TOPICS = {"/rosout", "/parameter_events"}

HEADER = """\
# Nodes

<!-- GENERATED, DO NOT EDIT: `python tools/gen_node_reference.py` writes this page from the node classes
     (changing_slam_ros/nodes/) and the hand-written text in docs/nodes_intro/. -->

The package's nodes, one section each: what the node does, then its publishers, subscriptions, services and
parameters as the code declares them. Topic names are the defaults; remap them with `--ros-args -r from:=to`
and set parameters with `-p name:=value` (`ros2 param describe /NODE NAME` shows a description too).
A row's *When* says when a topic exists only with some parameters, or not with them; empty: always.
Every node also has rclpy's standard parameters (`use_sim_time`, `start_type_description_service`) and
parameter services, and publishes `/rosout` and `/parameter_events`; `detection` is a lifecycle node and has
the lifecycle services (`~/change_state`, `~/get_state`, ...) and `~/transition_event` too. The QoS of
`/detection/detections` and of bag_player's publishers can be overridden with the standard
`qos_overrides.<topic>.publisher.<policy>` parameters (left out of the tables).

Run a node with `ros2 run changing_slam_ros NODE --ros-args ...` in a colcon workspace, or with
`python -m changing_slam_ros.nodes.NODE_node --ros-args ...` from a checkout; `--help` (before `--ros-args`)
prints the node's parameters with type, default and description and exits without starting ROS.
`changing-slam graph` starts bag_player, detection, tracking, local_mapping, loop_closing and object_map
together with the parameters they need.
"""


@dataclass
class NodeSpec:
    """How to build one node for the reference."""

    name: str  # the node's name, its section, and docs/nodes_intro/<name>.md
    module: str  # changing_slam_ros.nodes.<module>
    cls: str
    # (label shown in the *When* column, parameter overrides): rebuilt with these to find conditional topics
    variants: list[tuple[str, dict[str, Any]]] = field(default_factory=list)
    args: tuple[Any, ...] = ()  # positional arguments of the constructor
    configure: bool = False  # a lifecycle node: call trigger_configure() (creates its publishers)
    activate: bool = False  # and trigger_activate() (detection's image subscription exists only while active)
    # parameters whose reference value is not the built node's (bag_player is built with the sample bag)
    defaults: dict[str, Any] = field(default_factory=dict)
    # parameter overrides of every build (detection takes images at once instead of waiting for a subscriber)
    built_with: dict[str, Any] = field(default_factory=dict)


def _movers_config(tmp: Path) -> str:
    """config/sim.yaml with `dynamic.movers.enabled: true` (the tracking node's mover topics exist only then)."""
    import yaml

    data = yaml.safe_load((REPO / "config" / "sim.yaml").read_text()) or {}
    data.setdefault("dynamic", {}).setdefault("movers", {})["enabled"] = True
    path = tmp / "movers.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def node_specs(tmp: Path) -> list[NodeSpec]:
    """The nodes in the order of the page (the order of the data flow), with the variants read for each."""
    return [
        NodeSpec("bag_player", "bag_player_node", "BagPlayerNode", args=(str(SAMPLE_BAG),), defaults={"bag": ""},
                 variants=[("`lossless:=true` with `ack_topics` or `confirm_topics`",
                            {"lossless": True, "ack_topics": ["/camera/rgb/image_color"]})]),
        NodeSpec("detection", "detection_node", "DetectionNode", configure=True, activate=True,
                 built_with={"output_wait_s": 0.0}, defaults={"output_wait_s": 5.0},
                 variants=[("`compressed:=true`", {"compressed": True})]),
        NodeSpec("tracking", "tracking_node", "TrackingNode", variants=[
            ("`compressed:=true`", {"compressed": True}),
            ("`ack_topic:=/bag_player/ack` (the topic is the parameter)", {"ack_topic": "/bag_player/ack"}),
            ("the config's `dynamic.movers.enabled`", {"config": _movers_config(tmp)}),
            ("`in_process_backend:=true`", {"in_process_backend": True}),
            ("`slam:=false`", {"slam": False}),
            ("`debug_image:=false`", {"debug_image": False}),
            ("`publish_tf:=false`", {"publish_tf": False}),
        ]),
        NodeSpec("local_mapping", "local_mapping_node", "LocalMappingNode"),
        NodeSpec("loop_closing", "loop_closing_node", "LoopClosingNode"),
        NodeSpec("object_map", "object_map_node", "ObjectMapNode"),
    ]


@dataclass
class NodeFacts:
    """What one built node declares: rows of (name, type, qos) per kind, parameters as (name, type, default, text)."""

    publishers: list[tuple[str, str, str]]
    subscriptions: list[tuple[str, str, str]]
    services: list[tuple[str, str]]
    parameters: list[tuple[str, str, str, str]]


def _type_name(cls: Any, kind: str) -> str:
    return f"{cls.__module__.split('.')[0]}/{kind}/{cls.__name__}"


def _qos(profile: Any) -> str:
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy

    parts = ["best effort" if profile.reliability == ReliabilityPolicy.BEST_EFFORT else "reliable"]
    if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL:
        parts.append("transient local")
    parts.append("keep all" if profile.history == HistoryPolicy.KEEP_ALL else f"depth {profile.depth}")
    return ", ".join(parts)


def _value(value: Any) -> str:
    return f"`{format_value(value)}`"


def _parameter_type(type_id: int) -> str:
    from rclpy.parameter import Parameter

    name = Parameter.Type(type_id).name.lower()
    return name.replace("_array", "[]")


def read_node(node: Any, skip_topics: AbstractSet[str] = frozenset(), defaults: dict[str, Any] | None = None,
              ) -> NodeFacts:
    """The parameters, topics and services of a built node, in declaration order, rclpy's standard ones left out."""
    from rclpy.exceptions import ParameterUninitializedException

    def topic_rows(entities: Sequence[Any]) -> list[tuple[str, str, str]]:
        return [(e.topic_name, _type_name(e.msg_type, "msg"), _qos(e.qos_profile)) for e in entities
                if e.topic_name not in STANDARD_TOPICS and e.topic_name not in skip_topics]

    services = [(node.resolve_service_name(s.srv_name), _type_name(s.srv_type, "srv")) for s in node.services]
    services = [s for s in services if s[0].rsplit("/", 1)[-1] not in STANDARD_SERVICES]
    names = [n for n in node._parameters if n not in STANDARD_PARAMETERS and not n.startswith("qos_overrides.")]
    parameters = []
    for descriptor in node.describe_parameters(names):
        if defaults and descriptor.name in defaults:
            value = defaults[descriptor.name]
        else:
            try:
                value = node.get_parameter(descriptor.name).value
            except ParameterUninitializedException:  # an array declared by its type: empty
                value = None
        parameters.append((descriptor.name, _parameter_type(descriptor.type), _value(value), descriptor.description))
    return NodeFacts(topic_rows(node.publishers), topic_rows(node.subscriptions), services, parameters)


def build_node(spec: NodeSpec, context: Any, overrides: dict[str, Any]) -> Any:
    import importlib

    from rclpy.parameter import Parameter

    cls = getattr(importlib.import_module(f"changing_slam_ros.nodes.{spec.module}"), spec.cls)
    node = cls(*spec.args, context=context, parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
    if spec.configure:
        node.trigger_configure()
    if spec.activate:
        node.trigger_activate()
    return node


@contextmanager
def _built(spec: NodeSpec, context: Any, overrides: dict[str, Any]) -> Iterator[Any]:
    node = build_node(spec, context, overrides)
    try:
        yield node
    finally:
        node.destroy_node()


def _bag_topics(node: Any) -> set[str]:
    """bag_player's publishers of the bag's own topics (the bag decides them; the page describes them in words)."""
    return {pub.topic_name for pub in getattr(node, "bag_publishers", {}).values()}


def _with_conditions(default: list[tuple[str, ...]], variants: list[tuple[str, list[tuple[str, ...]]]],
                     ) -> list[tuple[str, ...]]:
    """The default node's rows plus each variant's new ones (keyed by their first column), with a *When* column:
    "with X" for a row only a variant has, "not with X" for a default row a variant lacks."""
    rows = {row[0]: row for row in default}
    when: dict[str, list[str]] = {key: [] for key in rows}
    only_with: set[str] = set()
    for label, variant_rows in variants:
        present = {row[0] for row in variant_rows}
        for key in list(rows):
            if key not in only_with and key not in present:
                when[key].append(f"not with {label}")
        for row in variant_rows:
            if row[0] not in rows:
                rows[row[0]] = row
                when[row[0]] = []
                only_with.add(row[0])
            if row[0] in only_with:
                when[row[0]].append(f"with {label}")
    return [(*row, "; ".join(when[key])) for key, row in rows.items()]


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def render_node(spec: NodeSpec, context: Any) -> str:
    """One node's section: its hand-written introduction, then the tables read from the built node."""
    with _built(spec, context, dict(spec.built_with)) as node:
        skip = _bag_topics(node)
        facts = read_node(node, skip, spec.defaults)
    variant_facts = []
    for label, overrides in spec.variants:
        with _built(spec, context, {**spec.built_with, **overrides}) as node:
            variant_facts.append((label, read_node(node, skip | _bag_topics(node))))
    intro = (INTROS / f"{spec.name}.md").read_text().strip()
    out = [f"## {spec.name}\n", intro + "\n"]
    code = lambda s: f"`{s}`"  # noqa: E731
    publishers = _with_conditions([tuple(r) for r in facts.publishers],
                                  [(lab, [tuple(r) for r in f.publishers]) for lab, f in variant_facts])
    subscriptions = _with_conditions([tuple(r) for r in facts.subscriptions],
                                     [(lab, [tuple(r) for r in f.subscriptions]) for lab, f in variant_facts])
    if skip:
        publishers.append(("each topic of the bag", "as recorded",
                           "reliable, depth `qos_depth` (`lossless`: keep all); transient local if latched", ""))
    for title, rows in (("Publishers", publishers), ("Subscriptions", subscriptions)):
        if rows:
            out.append(f"### {title}\n")
            out.append(_table(["Topic", "Type", "QoS", "When"],
                              [(code(t) if t.startswith("/") else t, code(ty) if "/" in ty else ty, q, w)
                               for t, ty, q, w in rows]))
    if facts.services:
        out.append("### Services\n")
        out.append(_table(["Service", "Type"], [(code(n), code(t)) for n, t in facts.services]))
    out.append("### Parameters\n")
    out.append(_table(["Name", "Type", "Default", "Description"],
                      [(code(n), t, d, text) for n, t, d, text in facts.parameters]))
    return "\n".join(out)


def render(context: Any) -> str:
    """The whole page, docs/nodes.md, built in `context` (an initialised rclpy Context)."""
    with tempfile.TemporaryDirectory() as tmp:
        sections = [render_node(spec, context) for spec in node_specs(Path(tmp))]
    return HEADER + "\n" + "\n".join(sections)


def undescribed_parameters(context: Any) -> list[str]:
    """`node.parameter` for every declared parameter without a description (none expected)."""
    missing = []
    with tempfile.TemporaryDirectory() as tmp:
        for spec in node_specs(Path(tmp)):
            with _built(spec, context, dict(spec.built_with)) as node:
                missing += [f"{spec.name}.{n}" for n, _, _, text in read_node(node).parameters if not text.strip()]
    return missing


def generate(render_page: Callable[[Any], str] = render) -> str:
    """Initialise a private rclpy context on a random local domain, render the page, shut the context down."""
    import rclpy

    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = rclpy.Context()
    rclpy.init(context=context, args=[], domain_id=random.randint(100, 200))
    try:
        return render_page(context)
    finally:
        context.try_shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 when docs/nodes.md differs from the code")
    parser.add_argument("--out", type=Path, default=DOC, help=f"page to write (default {DOC.relative_to(REPO)})")
    args = parser.parse_args(argv)
    text = generate()
    if args.check:
        if not args.out.is_file() or args.out.read_text() != text:
            print(f"{args.out}: out of date; run python tools/gen_node_reference.py", file=sys.stderr)
            return 1
        return 0
    args.out.write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
