"""MarkerArray of a change report (`core.objects.change_report`) for RViz / Foxglove.

After a DELETEALL, per change (numbered in report order): in namespace `changes_before` a hollow-looking sphere
(alpha 0.35) at the earlier place, in `changes_after` a solid sphere at the later place, in `changes_move` an
arrow from the one to the other (moved, replaced) and in `changes_label` a text "moved chair #1 2.03 m".
Colours: moved orange, removed red, added green, replaced purple.
"""

from __future__ import annotations

from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from changing_slam_ros.core.objects.change_report import ChangeKind, ChangeReport

KIND_RGB = {ChangeKind.MOVED: (1.0, 0.55, 0.0), ChangeKind.REMOVED: (0.9, 0.1, 0.1),
            ChangeKind.ADDED: (0.1, 0.8, 0.2), ChangeKind.REPLACED: (0.6, 0.2, 0.8)}
SPHERE_M = 0.2


def _point(v: tuple[float, float, float]) -> Point:
    return Point(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def change_markers(report: ChangeReport, header: Header) -> MarkerArray:
    """The markers of every change of `report`, in `header`'s frame (the maps' frame)."""
    out = MarkerArray(markers=[Marker(header=header, action=Marker.DELETEALL)])
    for i, c in enumerate(report.changes):
        r, g, b = KIND_RGB[c.kind]
        for ns, rec, alpha in (("changes_before", c.before, 0.35), ("changes_after", c.after, 0.9)):
            if rec is None:
                continue
            m = Marker(header=header, ns=ns, id=i, type=Marker.SPHERE, action=Marker.ADD)
            m.pose = Pose(position=_point(rec.centroid_w), orientation=Quaternion(w=1.0))
            m.scale = Vector3(x=SPHERE_M, y=SPHERE_M, z=SPHERE_M)
            m.color = ColorRGBA(r=r, g=g, b=b, a=alpha)
            out.markers.append(m)
        if c.before is not None and c.after is not None:
            arrow = Marker(header=header, ns="changes_move", id=i, type=Marker.ARROW, action=Marker.ADD)
            arrow.pose.orientation = Quaternion(w=1.0)
            arrow.points = [_point(c.before.centroid_w), _point(c.after.centroid_w)]
            arrow.scale = Vector3(x=0.03, y=0.08, z=0.1)  # shaft diameter, head diameter, head length
            arrow.color = ColorRGBA(r=r, g=g, b=b, a=1.0)
            out.markers.append(arrow)
        ref = c.after if c.after is not None else c.before
        assert ref is not None
        text = Marker(header=header, ns="changes_label", id=i, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD)
        p = _point(ref.centroid_w)
        text.pose = Pose(position=Point(x=p.x, y=p.y, z=p.z + 0.3), orientation=Quaternion(w=1.0))
        text.scale = Vector3(z=0.12)
        text.color = ColorRGBA(r=r, g=g, b=b, a=1.0)
        name = c.before.class_name if c.before is not None else ref.class_name
        text.text = f"{c.kind.value} {name} #{ref.id}" + ("" if c.distance_m is None else f" {c.distance_m:.2f} m")
        out.markers.append(text)
    return out
