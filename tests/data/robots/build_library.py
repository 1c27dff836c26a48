"""Write the built-in robot files that come from ROS-Industrial URDFs (run by hand).

    PYTHONPATH=src python tests/data/robots/build_library.py

Reads ``ros_industrial_urdfs.yaml`` (the numbers copied from the vendors' ROS-Industrial
xacro macros, with repository, path and commit) and writes
``src/kincal/robots/library/<name>.yaml`` as an ``ets`` chain with the URDF's own numbers
(lengths in m as in the URDF, angles in deg), the vendor's axis names and the controller's
joint map.  The chain's parameters are those kincal gives a URDF (``kincal.robots.urdf``).
tests/test_robot_library.py checks every written file against the fixture with numpy.
"""

from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

import yaml

from kincal.robots.files import robot_to_dict
from kincal.robots.urdf import load_urdf

HERE = Path(__file__).parent
LIB = HERE.parents[2] / "src" / "kincal" / "robots" / "library"

AXES = {"kuka": ["A1", "A2", "A3", "A4", "A5", "A6"],
        "abb": ["rax_1", "rax_2", "rax_3", "rax_4", "rax_5", "rax_6"],
        "fanuc": ["joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6"],
        "yaskawa": ["S", "L", "U", "R", "B", "T"],
        "kuka_lbr": ["A1", "A2", "A3", "A4", "A5", "A6", "A7"],
        "xarm6": ["J1", "J2", "J3", "J4", "J5", "J6"],
        "xarm7": ["J1", "J2", "J3", "J4", "J5", "J6", "J7"],
        "kinova": [f"joint_{i}" for i in range(1, 8)],
        "yumi": ["rax_1", "rax_2", "eax_a", "rax_3", "rax_4", "rax_5", "rax_6"]}

INFO = {
    "kr10r1100sixx": ("kuka", "KUKA", "KUKA KR 10 R1100 sixx (KR AGILUS), 6R industrial arm"),
    "kr16_2": ("kuka", "KUKA", "KUKA KR 16-2 (KR C2/KR C4), 6R industrial arm"),
    "kr16r1610_2": ("kuka", "KUKA", "KUKA KR 16 R1610-2 (KR CYBERTECH), 6R industrial arm"),
    "kr210r2700": ("kuka", "KUKA", "KUKA KR 210 R2700 extra (KR QUANTEC), 6R industrial arm"),
    "irb1200_7_70": ("abb", "ABB", "ABB IRB 1200-7/0.7, 6R industrial arm"),
    "irb1200_5_90": ("abb", "ABB", "ABB IRB 1200-5/0.9, 6R industrial arm"),
    "irb1600": ("abb", "ABB", "ABB IRB 1600-6/1.2, 6R industrial arm"),
    "irb2400": ("abb", "ABB", "ABB IRB 2400 (IRB 2400/10, /16), 6R industrial arm"),
    "irb4600": ("abb", "ABB", "ABB IRB 4600-60/2.05, 6R industrial arm"),
    "irb6700": ("abb", "ABB", "ABB IRB 6700-200/2.60, 6R industrial arm"),
    "gofa5": ("abb", "ABB", "ABB GoFa CRB 15000-5/0.95, 6R collaborative arm (wrist offset)"),
    "lrmate200id": ("fanuc", "FANUC", "FANUC LR Mate 200iD, 6R industrial arm"),
    "m20ia": ("fanuc", "FANUC", "FANUC M-20iA, 6R industrial arm"),
    "r2000ic165f": ("fanuc", "FANUC", "FANUC R-2000iC/165F, 6R industrial arm"),
    "crx10ial": ("fanuc", "FANUC", "FANUC CRX-10iA/L, 6R collaborative arm (wrist offset)"),
    "gp7": ("yaskawa", "Yaskawa", "Yaskawa Motoman GP7, 6R industrial arm"),
    "gp25": ("yaskawa", "Yaskawa", "Yaskawa Motoman GP25, 6R industrial arm"),
    "lbr_iiwa7": ("kuka_lbr", "KUKA", "KUKA LBR iiwa 7 R800, 7R collaborative arm"),
    "lbr_iiwa14": ("kuka_lbr", "KUKA", "KUKA LBR iiwa 14 R820, 7R collaborative arm"),
    "xarm6": ("xarm6", "UFACTORY", "UFACTORY xArm 6, 6R collaborative arm"),
    "xarm7": ("xarm7", "UFACTORY", "UFACTORY xArm 7, 7R collaborative arm"),
    "gen3": ("kinova", "Kinova", "Kinova Gen3 (7 DoF), 7R collaborative arm"),
    "yumi_r": ("yumi", "ABB", "ABB YuMi IRB 14000, right arm (ROB_R), 7R collaborative arm"),
    "yumi_l": ("yumi", "ABB", "ABB YuMi IRB 14000, left arm (ROB_L), 7R collaborative arm"),
}

NOTES = {
    "kuka": ("Joint variables, zero positions and directions are KUKA's A1 ... A6 (E6AXIS, deg): "
             "A1, A4 and A6 turn about -z, -x, -x of the base at q = 0, as in the URDF. q = 0 is "
             "the arm stretched forward and horizontal (KUKA's HOME is A2 = -90, A3 = +90). The "
             "tool frame ry = 90 deg makes the end frame KUKA's $FLANGE (ROS-Industrial's tool0); "
             "frame 0 is $ROBROOT."),
    "abb": ("Joint variables and directions are ABB's (rax_1 ... rax_6 of a RAPID jointtarget, "
            "deg): q = 0 is the calibration position (upper arm vertical, forearm horizontal). "
            "The tool frame ry = 90 deg makes the end frame ABB's tool0 (z out of the flange, "
            "x down at q = 0); frame 0 is the base frame on the mounting surface."),
    "fanuc": ("Model joints are the URDF's joint_1 ... joint_6; the controller's J1 ... J6 (deg) "
              "map to them with FANUC's J2/J3 interaction: joint_3 = J2 + J3 (J3 is the "
              "forearm's angle to the horizontal, the URDF's joint_3 its angle to the upper "
              "arm), the other joints are the axes. At J = 0 the upper arm is vertical, the "
              "forearm horizontal and the faceplate faces forward with W, P, R = 180, -90, 0. "
              "The base frame puts FANUC's world frame at the height of J2, as the controller "
              "does (ROS-Industrial's `base`); the end frame is the faceplate (tool 0)."),
    "yaskawa": ("Model joints are Yaskawa's S, L, U, R, B, T with the directions of the "
                "ROS-Industrial URDF, which are the joint values MotoROS reports (rad); the "
                "pendant's pulse counts are not mapped here. At zero the lower arm (L) is "
                "vertical and the upper arm (U) horizontal. The base frame puts the robot's "
                "world frame at the height of L (ROS-Industrial's `base`); the end frame is "
                "tool0 (z out of the flange, x up at zero)."),
    "kuka_lbr": ("Joint variables are KUKA's A1 ... A7 (deg) with the directions of the "
                 "ROS-Industrial URDF (A4 turns about -y). q = 0 is the arm stretched "
                 "upright. The end frame is the flange (tool0, 126 mm beyond A6/A7). The "
                 "URDF's +-0.436 mm x offsets at A2 and A4 are kept as published (KUKA's "
                 "dimension drawing puts the axes through each other)."),
    "xarm6": ("Joint variables are the xArm's J1 ... J6 as its SDK and xArm Studio give them "
              "(deg), each turning about the z axis of its URDF frame. q = 0 is the xArm's zero "
              "position. The end frame is the tool flange (link6)."),
    "xarm7": ("Joint variables are the xArm's J1 ... J7 as its SDK and xArm Studio give them "
              "(deg), each turning about the z axis of its URDF frame. q = 0 is the xArm's zero "
              "position. The end frame is the tool flange (link7)."),
    "kinova": ("Joint variables are the Gen3's joint_1 ... joint_7 (deg), each turning about "
               "the z axis of its URDF frame; joints 1, 3, 5 and 7 turn without limit. The "
               "Kortex API reports joint angles in 0 ... 360 deg: for the limited joints 2, 4 "
               "and 6 subtract 360 from values above 180. The end frame is Kinova's "
               "EndEffector_Link (the tool flange, z out of it)."),
    "yumi": ("Joint variables are ABB's (deg): rax_1 ... rax_6 and axis 7, which RAPID carries "
             "in the external axis eax_a of a jointtarget and of a robtarget (the arm angle). "
             "In the chain axis 7 sits between axes 2 and 3 (model joints rax_1, rax_2, eax_a, "
             "rax_3 ... rax_6); the controller map lists the axes in RAPID's order. Frame 0 is "
             "the YuMi's world (body) frame on the mounting surface, in which both arms' "
             "robtargets are written (wobj0); the end frame is tool0, the flange the gripper "
             "is bolted to. At the synchronization position (axes 0, -130, 30, 0, 40, 0, "
             "axis 7 -135 right / +135 left) the URDF's numbers put tool0 within 2 mm and "
             "0.2 deg of the pose the controller reports (the URDF's shoulder mount is "
             "given to 4 decimals and is not ABB's calibrated geometry)."),
}


def _limit_deg(v: float, unit: str) -> float:
    if unit == "deg":
        return float(v)
    d = math.degrees(v)
    # The URDF writes the datasheet's degrees as radians to 3-4 decimals: give the whole degree
    # when it is within that rounding, else the converted value to 0.01 deg.
    return float(round(d)) if abs(d - round(d)) < 0.03 else round(d, 2)


def snap_quarter_turns(rpy: list[float]) -> list[float]:
    """The file's angles [rad], with values within 1e-4 rad of a multiple of pi/2 (1.5708 for
    pi/2) replaced by that multiple: the axes are perpendicular by design."""
    out = []
    for v in rpy:
        k = round(v / (math.pi / 2))
        out.append(k * math.pi / 2 if abs(v - k * math.pi / 2) < 1e-4 else float(v))
    return out


def _urdf_text(spec: dict, names: list[str]) -> str:
    links = ["base_link"] + [f"link_{i}" for i in range(1, len(names) + 1)]
    out = ['<robot name="r">'] + [f'<link name="{n}"/>' for n in links]
    rpys = spec.get("rpy") or [[0, 0, 0]] * len(names)
    for i, (xyz, ax) in enumerate(zip(spec["xyz"], spec["axis"], strict=True)):
        rpy = " ".join(map(repr, snap_quarter_turns(rpys[i])))
        out.append(f'<joint name="{names[i]}" type="revolute">'
                   f'<origin xyz="{" ".join(map(repr, map(float, xyz)))}" rpy="{rpy}"/>'
                   f'<parent link="{links[i]}"/><child link="{links[i + 1]}"/>'
                   f'<axis xyz="{" ".join(map(str, ax))}"/>'
                   '<limit lower="-1" upper="1" effort="0" velocity="1"/></joint>')
    return "\n".join(out + ["</robot>"])


def build(name: str, spec: dict) -> str:
    key, vendor, desc = INFO[name]
    names = AXES[key]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r.urdf"
        path.write_text(_urdf_text(spec, names), encoding="utf-8")
        doc = robot_to_dict(load_urdf(path), as_ets=True)
    chain = []
    for row in doc["chain"]:
        row = dict(row)
        if row["transform"].startswith("R"):
            row["value"] = math.degrees(row["value"])
        chain.append(row)
    joints: list[dict] = []
    for n, lim in zip(names, spec["limits"], strict=True):
        row: dict = {"name": n, "type": "revolute"}
        if lim is not None:         # a continuous joint has none
            row["limits"] = [_limit_deg(v, spec["limit_unit"]) for v in lim]
        joints.append(row)
    base = spec.get("base") or {"xyz": [0, 0, 0]}
    t0 = spec["tool0"]
    rpy = t0["rpy"] if not (key == "abb" and t0["rpy"] == [0, 0, 0]) else [0, 90, 0]
    src = (f"ROS-Industrial URDF {spec['repo']} {spec['path']}, commit {spec['commit'][:12]}: "
           f"joint origins, axes and limits of its {len(names)} joints, the transform from "
           "the last link to tool0")
    if key == "fanuc":
        src += " and the base_link -> base offset (FANUC's world frame at J2)"
    elif key == "yaskawa":
        src += " and the base_link -> base offset"
    if key == "yumi":
        src += (" and the gripper mount on link_7 in yumi_description/urdf/yumi.urdf.xacro "
                "(tool0: 7 mm along z, turned 180 deg about z)")
    src += ". Lengths are the URDF's, in m."
    if key == "fanuc":
        src += (" J2/J3 coupling: ROS-Industrial's fanuc driver with J23_factor = 1 (joint_3 = "
                "J2 + J3).")
    if spec["limit_unit"] == "rad":
        src += (" The URDF gives the limits in rad to a few decimals; they are written here in "
                "deg, as the whole degree they round.")
    if spec.get("rpy") and key != "yumi":
        src += (" The URDF writes the joint origins' quarter turns as 1.5708 rad; they are "
                "exact multiples of pi/2 here (the axes are perpendicular by design).")
    if key == "abb" and t0["rpy"] == [0, 0, 0]:
        src += (" This URDF leaves tool0 = link_6; the tool frame ry = 90 deg is ABB's tool0, as "
                "in the other ROS-Industrial ABB URDFs.")
    out = {
        "name": name, "vendor": vendor, "description": desc, "source": src,
        "notes": NOTES[key],
        "units": {"length": "m", "angle": "deg"}, "convention": "ets",
        "base": {"x": 0, "y": 0, "z": -float(base["xyz"][2]), "rx": 0, "ry": 0, "rz": 0},
        "tool": {"x": float(t0["xyz"][0]), "y": float(t0["xyz"][1]), "z": float(t0["xyz"][2]),
                 "rx": float(rpy[0]), "ry": float(rpy[1]), "rz": float(rpy[2])},
        "joints": joints, "chain": chain,
    }
    if key == "fanuc":
        out["controller"] = {"vendor": "fanuc", "axes": ["J1", "J2", "J3", "J4", "J5", "J6"],
                             "unit": "deg",
                             "joints": {"joint_1": {"J1": 1}, "joint_2": {"J2": 1},
                                        "joint_3": {"J2": 1, "J3": 1}, "joint_4": {"J4": 1},
                                        "joint_5": {"J5": 1}, "joint_6": {"J6": 1}}}
    elif key == "yumi":
        out["controller"] = {"vendor": "abb",
                             "axes": ["rax_1", "rax_2", "rax_3", "rax_4", "rax_5", "rax_6",
                                      "eax_a"], "unit": "deg",
                             "joints": {n: {n: 1} for n in names}}
    elif key in ("kuka_lbr", "xarm6", "xarm7", "kinova"):
        out["controller"] = {"axes": names, "unit": "deg"}
    elif key == "yaskawa":
        out["controller"] = {"axes": names, "unit": "rad"}
    else:
        out["controller"] = {"vendor": key, "axes": names, "unit": "deg"}
    text = yaml.safe_dump(out, sort_keys=False, width=100, default_flow_style=None)
    return "# Generated by tests/data/robots/build_library.py from the URDF numbers below.\n" + text


def main() -> int:
    fixture = yaml.safe_load((HERE / "ros_industrial_urdfs.yaml").read_text(encoding="utf-8"))
    for name, spec in fixture.items():
        (LIB / f"{name}.yaml").write_text(build(name, spec), encoding="utf-8")
        print("wrote", name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
