"""Acceptance of `quickhealth plan` on the reference cell with N = 150 (issue 4).

The planner is checked by an independent implementation: pinocchio's own URDF parser and its
collision library (coal, not python-fcl), a Newton IK tracker instead of the analytic one,
OpenCV's projection for the fields of view, and finer sampling than the planner uses.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import json
import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np
import pytest

from quickhealth.identify.errors import InputError
from quickhealth.identify.robot import ur5
from quickhealth.station.cli import main
from quickhealth.station.planning.cell import load_cell
from quickhealth.station.planning.collision import CollisionWorld
from quickhealth.station.planning.planfile import load_plan, plan_from_dict
from quickhealth.station.planning.urscript import render_urscript

pin = pytest.importorskip("pinocchio")
coal = pytest.importorskip("coal")

pytestmark = pytest.mark.slow

N = 150
LINEAR_STEP_M = 0.001
LINEAR_STEP_RAD = math.radians(0.25)
JOINT_STEP_RAD = math.radians(0.5)
MAX_JOINT_STEP_PER_MM = math.radians(1.0)  # ≙ 250°/s at 250 mm/s: a jump, not a motion


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    out = tmp_path_factory.mktemp("plan")
    rc = main(["plan", "--cell", "reference", "--n", str(N), "--seed", "0", "--out", str(out)])
    assert rc == 0
    return out, load_plan(out / "plan.json"), load_cell("reference")


# ---------------------------------------------------------------- independent checker
def _share() -> Path:
    for f in importlib.metadata.files("example-robot-data") or []:
        if str(f).endswith("ur_description/urdf/ur5_robot.urdf"):
            return Path(str(f.locate())).parents[4]
    raise AssertionError("example-robot-data not found")


def _se3(T):
    return pin.SE3(np.array(T[:3, :3]), np.array(T[:3, 3]))


class Independent:
    """pinocchio + coal model of the cell; the URDF base is the DH base turned 180° about z."""

    def __init__(self, cell):
        share = _share()
        desc = share / "example-robot-data" / "robots" / "ur_description"
        urdf = str(desc / "urdf" / "ur5_robot.urdf")
        self.cell = cell
        self.model = pin.buildModelFromUrdf(urdf)
        gm = pin.buildGeomFromUrdf(
            self.model, urdf, pin.GeometryType.COLLISION, package_dirs=[str(share)]
        )
        gm.removeGeometryObject("ee_link_0")
        Rz = np.diag([-1.0, -1.0, 1.0, 1.0])
        self.T_world_urdf = cell.T_world_base @ Rz
        self.T_urdf_world = np.linalg.inv(self.T_world_urdf)
        tool0 = self.model.frames[self.model.getFrameId("tool0")]
        joint = tool0.parentJoint
        T_j_tool0 = tool0.placement.homogeneous
        T_j_target = T_j_tool0 @ cell.T_flange_target
        self.fid = self.model.addFrame(
            pin.Frame(
                "qh_target",
                joint,
                self.model.getFrameId("tool0"),
                _se3(T_j_target),
                pin.FrameType.OP_FRAME,
            )
        )
        self.data = self.model.createData()
        n_robot = len(gm.geometryObjects)
        gm.addGeometryObject(
            pin.GeometryObject(
                "target",
                joint,
                _se3(T_j_target @ cell.T_target_body),
                coal.Box(*cell.target_body_size),
            )
        )
        statics = []
        for o in cell.obstacles:
            geo = coal.Box(*o.size) if o.shape == "box" else coal.Cylinder(o.radius, o.length)
            statics.append(
                gm.addGeometryObject(
                    pin.GeometryObject(o.name, 0, _se3(self.T_urdf_world @ o.T_world_obstacle), geo)
                )
            )
        size = np.r_[cell.table_max_xy - cell.table_min_xy, cell.table_thickness]
        ctr = np.r_[
            (cell.table_max_xy + cell.table_min_xy) / 2,
            cell.table_top_z - cell.table_thickness / 2,
            1.0,
        ]
        Tt = np.eye(4)
        Tt[:, 3] = ctr
        statics.append(
            gm.addGeometryObject(
                pin.GeometryObject("table", 0, _se3(self.T_urdf_world @ Tt), coal.Box(*size))
            )
        )
        srdf = ET.parse(desc / "srdf" / "ur5.srdf").getroot()
        disabled = {
            frozenset((d.get("link1") + "_0", d.get("link2") + "_0"))
            for d in srdf.iter("disable_collisions")
        }
        names = [g.name for g in gm.geometryObjects]
        it = names.index("target")
        for i in range(n_robot):
            for j in range(i + 1, n_robot):
                if frozenset((names[i], names[j])) not in disabled:
                    gm.addCollisionPair(pin.CollisionPair(i, j))
            if names[i] != "wrist_3_link_0":
                gm.addCollisionPair(pin.CollisionPair(i, it))
        for s in statics:
            for i in [*range(n_robot), it]:
                if not (names[s] == "table" and names[i] == "base_link_0"):
                    gm.addCollisionPair(pin.CollisionPair(i, s))
        self.gm = gm
        self.gd = pin.GeometryData(gm)
        self.names = names
        self.n_robot = n_robot

    def collides(self, q) -> bool:
        return bool(
            pin.computeCollisions(
                self.model, self.data, self.gm, self.gd, np.asarray(q, float), True
            )
        )

    def T_world_target(self, q):
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, float))
        return self.T_world_urdf @ self.data.oMf[self.fid].homogeneous

    def track_linear(self, q0, T_a, T_b):
        """Newton IK along the straight line (world frame), step by step from q0."""
        d = np.linalg.norm(T_b[:3, 3] - T_a[:3, 3])
        w = pin.log3(T_a[:3, :3].T @ T_b[:3, :3])
        m = int(
            max(2, math.ceil(d / LINEAR_STEP_M), math.ceil(np.linalg.norm(w) / LINEAR_STEP_RAD))
        )
        q = np.array(q0, float)
        qs = [q.copy()]
        for s in np.linspace(0.0, 1.0, m + 1)[1:]:
            T = np.eye(4)
            T[:3, :3] = T_a[:3, :3] @ pin.exp3(s * w)
            T[:3, 3] = T_a[:3, 3] + s * (T_b[:3, 3] - T_a[:3, 3])
            des = _se3(self.T_urdf_world @ T)
            for _ in range(30):
                pin.framesForwardKinematics(self.model, self.data, q)
                err = pin.log6(self.data.oMf[self.fid].actInv(des)).vector
                if np.linalg.norm(err) < 1e-11:
                    break
                J = pin.computeFrameJacobian(self.model, self.data, q, self.fid, pin.LOCAL)
                q = q + np.linalg.lstsq(J, err, rcond=None)[0]
            else:
                raise AssertionError(f"Newton IK did not converge at s = {s:.4f}")
            qs.append(q.copy())
        return np.array(qs), d / m


def _world_targets(plan, cell):
    return [cell.T_world_base @ p.T_base_target for p in plan.poses]


# ---------------------------------------------------------------- acceptance 1
def test_summary_states_generated_kept_and_dropped_by_reason(planned):
    out, plan, cell = planned
    s = plan.summary
    assert s["generated"] == N
    assert s["kept"] == len(plan.poses)
    assert s["kept"] + sum(s["dropped"].values()) == N
    assert len(plan.dropped) == sum(s["dropped"].values())
    for reason, count in s["dropped"].items():
        assert count == sum(d["reason"] == reason for d in plan.dropped)
    assert all(d["detail"] for d in plan.dropped)
    # the paper kept 78 of 150; the reference cell keeps about half as well
    assert 50 <= s["kept"] <= 110
    assert s["legs"]["linear"] >= 15
    assert (out / "fig6_joints.png").stat().st_size > 10000
    assert (out / "fig6_targets.png").stat().st_size > 10000


# ---------------------------------------------------------------- acceptance 2
def test_independent_recheck_of_every_leg_and_line_of_sight(planned):
    _, plan, cell = planned
    ind = Independent(cell)
    # the independent model agrees with the DH model (and so with the planner's frames)
    for p in plan.poses[:10]:
        assert np.allclose(ind.T_world_target(p.q), cell.T_world_base @ p.T_base_target, atol=1e-9)
    targets = _world_targets(plan, cell)
    legs = [(k - 1, k, plan.poses[k].leg) for k in range(1, len(plan.poses))]
    legs.append((len(plan.poses) - 1, 0, plan.return_leg))
    assert plan.home is not None  # the reference cell starts from a home position
    assert not ind.collides(plan.home)
    legs.insert(0, ("home", 0, plan.poses[0].leg))
    n_checked = 0
    for a, b, leg in legs:
        qa = plan.home if a == "home" else plan.poses[a].q
        qb = plan.poses[b].q
        if leg.value == "linear":
            qs, step = ind.track_linear(qa, targets[a], targets[b])
            jump = np.abs(np.diff(qs, axis=0)).max() / (step * 1000.0)
            assert jump <= MAX_JOINT_STEP_PER_MM, (
                f"leg {a}->{b}: IK jumps {math.degrees(jump):.2f}°/mm"
            )
            assert np.allclose(qs[-1], qb, atol=1e-6), f"leg {a}->{b} ends in another configuration"
        else:
            m = int(max(2, math.ceil(np.abs(qb - qa).max() / JOINT_STEP_RAD)))
            qs = qa + np.linspace(0.0, 1.0, m + 1)[:, None] * (qb - qa)
        assert np.all(qs >= cell.robot.q_min - 1e-9) and np.all(qs <= cell.robot.q_max + 1e-9)
        for q in qs:
            assert not ind.collides(q), (
                f"leg {a}->{b} ({leg.value}) collides at q = {np.degrees(q).round(1)}"
            )
        n_checked += len(qs)
    assert n_checked > 5 * len(legs)

    # line of sight at every kept pose: FOV (OpenCV projection), facing, occlusion (coal)
    cam = cell.camera
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
    for p, T in zip(plan.poses, targets, strict=True):
        pin.updateGeometryPlacements(ind.model, ind.data, ind.gm, ind.gd, p.q)
        n = T[:3, :3] @ np.array([math.sin(p.pan), 0.0, math.cos(p.pan)])
        for Tc in (cell.T_world_cam_left, cell.T_world_cam_right):
            Tcw = np.linalg.inv(Tc)
            rvec, _ = cv2.Rodrigues(Tcw[:3, :3])
            uv = cv2.projectPoints(T[None, :3, 3], rvec, Tcw[:3, 3], K, None)[0].ravel()
            depth = (Tcw @ np.r_[T[:3, 3], 1.0])[2]
            assert cam.min_range <= depth <= cam.max_range
            assert cam.margin_px <= uv[0] <= cam.width - cam.margin_px
            assert cam.margin_px <= uv[1] <= cam.height - cam.margin_px
            c = Tc[:3, 3]
            u = (c - T[:3, 3]) / np.linalg.norm(c - T[:3, 3])
            assert (
                math.degrees(math.acos(np.clip(n @ u, -1, 1)))
                <= math.degrees(cell.facing_max) + 1e-6
            )
            a = c - 0.05 * u
            b = T[:3, 3] + cell.planner.sight_stop * u
            L = np.linalg.norm(b - a)
            z = (b - a) / L
            x = np.cross(z, [0.0, 0.0, 1.0])
            x /= np.linalg.norm(x)
            Tb = np.eye(4)
            Tb[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
            Tb[:3, 3] = (a + b) / 2
            beam = coal.Cylinder(cell.planner.sight_radius, L)
            beam_tf = coal.Transform3s(*(lambda M: (M[:3, :3], M[:3, 3]))(ind.T_urdf_world @ Tb))
            for g, go in enumerate(ind.gm.geometryObjects):
                if go.name == "target":
                    continue
                res = coal.CollisionResult()
                coal.collide(
                    beam, beam_tf, go.geometry, ind.gd.oMg[g], coal.CollisionRequest(), res
                )
                assert not res.isCollision(), f"{p.name}: sight blocked by {go.name}"
    # negative control: the same beam test sees the robot when aimed at its shoulder
    pin.updateGeometryPlacements(ind.model, ind.data, ind.gm, ind.gd, plan.poses[0].q)
    c = cell.T_world_cam_left[:3, 3]
    shoulder = cell.T_world_base[:3, 3] + [0.0, 0.0, 0.1]
    L = np.linalg.norm(shoulder - c)
    z = (shoulder - c) / L
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    Tb = np.eye(4)
    Tb[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    Tb[:3, 3] = (c + shoulder) / 2
    Tb = ind.T_urdf_world @ Tb
    hits = []
    for g, go in enumerate(ind.gm.geometryObjects):
        res = coal.CollisionResult()
        coal.collide(
            coal.Cylinder(0.01, L),
            coal.Transform3s(Tb[:3, :3], Tb[:3, 3]),
            go.geometry,
            ind.gd.oMg[g],
            coal.CollisionRequest(),
            res,
        )
        if res.isCollision():
            hits.append(go.name)
    assert "shoulder_link_0" in hits


def test_independent_collision_model_agrees_on_random_configurations():
    cell = load_cell("reference")
    exact = dataclasses.replace(cell, planner=dataclasses.replace(cell.planner, clearance=0.0))
    ind = Independent(exact)
    w = CollisionWorld(exact)
    q = np.random.default_rng(5).uniform(-np.pi, np.pi, (400, 6))
    mine = w.collides(q)
    theirs = np.array([ind.collides(x) for x in q])
    assert 0.2 < mine.mean() < 0.95
    assert np.mean(mine == theirs) >= 0.99


# ---------------------------------------------------------------- acceptance 3
def test_every_joint_covers_70_percent_of_its_usable_range(planned):
    _, plan, _ = planned
    j = plan.summary["joints"]
    lo, hi = np.array(j["usable_min_deg"]), np.array(j["usable_max_deg"])
    q = np.degrees(plan.q)
    inside = np.maximum(np.minimum(q.max(0), hi) - np.maximum(q.min(0), lo), 0.0)
    coverage = inside / (hi - lo)
    assert np.all(coverage >= 0.70), coverage
    assert np.allclose(coverage, j["coverage"], atol=1e-3)
    # evenness (normalised histogram entropy) recomputed and reported
    for k in range(6):
        h, _ = np.histogram(q[:, k], bins=j["bins"], range=(lo[k], hi[k]))
        p = h[h > 0] / h.sum()
        assert -(p * np.log(p)).sum() / math.log(j["bins"]) == pytest.approx(
            j["evenness"][k], abs=1e-3
        )
    assert min(j["evenness"]) > 0.8
    assert "entropy" in j["evenness_criterion"]


# ---------------------------------------------------------------- acceptance 4
_LINE = [
    re.compile(p)
    for p in (
        r"#.*",
        r"def [a-z_]+\((index)?\):",
        r"end",
        r"set_tcp\(p\[(-?\d+\.\d+, ){5}-?\d+\.\d+\]\)",
        r'textmsg\("[^"\\]*"(, index)?\)',
        r"sleep\(\d+\.\d+\)",
        r"write_output_integer_register\(\d+, (index|-1)\)",
        r"qh_t = 0\.0",
        r"while read_input_integer_register\(\d+\) != index:",
        r"sync\(\)",
        r"qh_t = qh_t \+ get_steptime\(\)",
        r"if qh_t > \d+\.\d+:",
        r"halt",
        r"qh_pass = 0",
        r"while qh_pass < \d+:",
        r"qh_measure\(\d+\)",
        r"qh_pass = qh_pass \+ 1",
        r"if qh_pass < \d+:",
        r"move[jl]\(\[(-?\d+\.\d+, ){5}-?\d+\.\d+\], a=\d+\.\d+, v=\d+\.\d+\)",
        r"qh_home = \[(-?\d+\.\d+, ){5}-?\d+\.\d+\]",
        r"qh_now = get_actual_joint_positions\(\)",
        r"qh_j = 0",
        r"while qh_j < 6:",
        r"if norm\(qh_now\[qh_j\] - qh_home\[qh_j\]\) > \d+\.\d+:",
        r"qh_j = qh_j \+ 1",
    )
]


def _parse_urscript(text):
    depth = 0
    moves = []
    measures = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line:
            continue
        indent = len(raw) - len(raw.lstrip(" "))
        assert any(p.fullmatch(line) for p in _LINE), f"line {n}: unexpected statement {line!r}"
        if line == "end":
            depth -= 1
            assert depth >= 0, f"line {n}: unbalanced end"
        if not line.startswith("#"):
            assert indent == 2 * depth, f"line {n}: indentation {indent} at depth {depth}"
        if re.match(r"(def|while|if) ", line):
            assert line.endswith(":")
            depth += 1
        m = re.fullmatch(r"(move[jl])\(\[(.*)\], a=(.*), v=(.*)\)", line)
        if m:
            moves.append(
                (
                    m.group(1),
                    np.array([float(x) for x in m.group(2).split(",")]),
                    float(m.group(3)),
                    float(m.group(4)),
                )
            )
        m = re.fullmatch(r"qh_measure\((\d+)\)", line)
        if m:
            measures.append(int(m.group(1)))
    assert depth == 0, "unbalanced blocks"
    return moves, measures


def test_urscript_parses_and_replays_the_plan(planned):
    out, plan, cell = planned
    text = (out / "loop.script").read_text()
    assert text.splitlines()[3] == "def quickhealth_loop():"
    assert plan.hash.split(":")[1] in text
    moves, measures = _parse_urscript(text)
    k = len(plan.poses)
    assert measures == list(range(1, k + 1))
    assert len(moves) == k + 1  # every pose plus the return leg
    robot = ur5()
    T_ft = cell.T_flange_target
    for j, p in enumerate(plan.poses):
        kind, q, a, v = moves[j]
        assert np.all(q >= cell.robot.q_min - 1e-9) and np.all(q <= cell.robot.q_max + 1e-9)
        assert np.allclose(q, p.q, atol=1e-8)
        assert kind == ("movej" if j == 0 or p.leg.value == "joint" else "movel")
        if kind == "movel":
            assert v == pytest.approx(cell.motion.linear_speed) and a == pytest.approx(
                cell.motion.linear_accel
            )
        else:
            assert v == pytest.approx(cell.motion.joint_speed) and a == pytest.approx(
                cell.motion.joint_accel
            )
        T = robot.fk(q) @ T_ft  # replay through forward kinematics
        assert np.allclose(T[:3, 3], p.T_base_target[:3, 3], atol=1e-7)
        assert np.allclose(T[:3, :3], p.T_base_target[:3, :3], atol=1e-7)
    assert np.allclose(moves[-1][1], plan.poses[0].q, atol=1e-8)


# ---------------------------------------------------------------- plan files are data
def test_plan_hash_and_hostile_pose_names(planned, tmp_path):
    out, plan, _ = planned
    doc = json.loads((out / "plan.json").read_text())
    assert plan_from_dict(doc).hash == doc["hash"]
    # any edit breaks the hash
    doc2 = json.loads(json.dumps(doc))
    doc2["poses"][0]["pan_deg"] += 1.0
    with pytest.raises(InputError, match=r"hash: content does not match"):
        plan_from_dict(doc2, "plan.json")
    # a pose name carrying URScript is refused even with a recomputed hash
    from quickhealth.station.planning.planfile import content_hash

    doc3 = json.loads(json.dumps(doc))
    doc3["poses"][1]["name"] = 'P2\n  popup("x")\n  socket_open("10.0.0.1", 80)'
    doc3["hash"] = content_hash(doc3)
    p = tmp_path / "evil.json"
    p.write_text(json.dumps(doc3))
    with pytest.raises(
        InputError, match=r"evil\.json: poses\[1\]\.name: .* not a plain identifier"
    ) as e:
        load_plan(p)
    assert "\n" not in str(e.value)
    # and the URScript writer checks names again on its own
    forged = dataclasses.replace(
        plan, poses=(plan.poses[0], dataclasses.replace(plan.poses[1], name='x")\nhalt\n#'))
    )
    with pytest.raises(InputError, match="pose name"):
        render_urscript(forged)
    # joint targets outside the limits are refused
    doc4 = json.loads(json.dumps(doc))
    doc4["poses"][2]["q_deg"][1] = 200.0
    doc4["hash"] = content_hash(doc4)
    with pytest.raises(InputError, match=r"poses\[2\]\.q_deg\[1\]: 200° outside"):
        plan_from_dict(doc4, "plan.json")
    # NaN is not JSON
    p.write_text((out / "plan.json").read_text().replace('"pan_deg": ', '"pan_deg": NaN, "x": ', 1))
    with pytest.raises(InputError, match="not a JSON plan file"):
        load_plan(p)
