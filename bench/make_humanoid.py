"""Write test/urdf/humanoid.urdf: a 34-link, 33-joint humanoid-size tree used by the DDS benchmark
and the Pinocchio tests (torso 3, head 2, arms 2 x 7, legs 2 x 6, grippers 2 x 1 prismatic).

Usage: python bench/make_humanoid.py
"""

from __future__ import annotations

from pathlib import Path

OUT = Path(__file__).resolve().parent.parent / "test" / "urdf" / "humanoid.urdf"
AXES = ("1 0 0", "0 1 0", "0 0 1")


def link(name: str, com: str, mass: float = 1.0) -> str:
    return (
        f'  <link name="{name}"><inertial><origin xyz="{com}" rpy="0 0 0"/><mass value="{mass}"/>'
        '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>'
    )


def joint(name: str, kind: str, parent: str, child: str, xyz: str, axis: str, rpy: str = "0 0 0") -> str:
    limit = '<limit lower="-2" upper="2" effort="100" velocity="5"/>' if kind != "fixed" else ""
    return (
        f'  <joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="{axis}"/>{limit}</joint>'
    )


def chain(lines: list[str], prefix: str, parent: str, count: int, start: str, step: str, rpy: str = "0 0 0") -> str:
    for k in range(count):
        name = f"{prefix}_{k + 1}"
        lines.append(link(name, "0.01 0.005 -0.05", 1.5 - 0.1 * k))
        lines.append(
            joint(
                f"{name}_joint",
                "revolute",
                parent,
                name,
                start if k == 0 else step,
                AXES[k % 3],
                rpy if k == 0 else "0 0 0",
            )
        )
        parent = name
    return parent


def main() -> None:
    lines = ['<?xml version="1.0"?>', '<robot name="humanoid">', link("pelvis", "0 0 0.05", 8.0)]
    torso = chain(lines, "torso", "pelvis", 3, "0 0 0.1", "0 0 0.12")
    chain(lines, "head", torso, 2, "0 0 0.2", "0 0 0.05")
    for side, sign in (("left", 1), ("right", -1)):
        hand = chain(lines, f"{side}_arm", torso, 7, f"0 {0.2 * sign} 0.15", "0 0 -0.12", f"{0.3 * sign} 0 0")
        lines.append(link(f"{side}_finger", "0 0 -0.02", 0.1))
        lines.append(joint(f"{side}_finger_joint", "prismatic", hand, f"{side}_finger", "0 0 -0.05", "0 1 0"))
        chain(lines, f"{side}_leg", "pelvis", 6, f"0 {0.1 * sign} -0.05", "0 0 -0.2")
    lines.append("</robot>")
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
