"""Writes the FBX/glTF motion fixtures of ``tests/data/fbx`` with Blender, the independent reference.

Run with a Python that has Blender as a module (``pip install bpy==4.5.4`` in a Python 3.11 venv;
not a project dependency, the tests read only the files this writes):

    /path/to/bpy-venv/bin/python scripts/make_fbx_fixtures.py

1. ``walk.bvh``: the test skeleton (``tests/motion_files.SKELETON``, centimetres, Y up) with seeded
   random rotations on every joint and a root that walks, written here as plain text.
2. ``blender_walk.fbx`` / ``blender_walk.glb``: Blender's BVH import of it (at 0.01: metres), with a
   small mesh skinned to the armature, exported by Blender's own FBX and glTF exporters (binary FBX
   7.4, baked keys on every frame, exported while the scene stands at frame 5, so that the models'
   own transform values are a walking frame and the rest pose is only in the bind pose).
3. ``joint_orient.fbx``: written by ``tests/fbx_files.write_fbx`` the way Maya and MotionBuilder
   write rigs (PreRotation on every joint, some PostRotation, rotation orders other than XYZ, a
   rotation pivot, an armature node turned and scaled above the skeleton).
4. ``root_bone.bvh``: the walk under a game rig's 'root' bone that walks and turns (the hips its
   only child, with their own position channels).
5. ``*.blender.npz``: for each FBX and ``root_bone.bvh``, Blender's import of it, sampled at every
   frame: each bone's head in world space (Blender's Z-up scene) -- what the tests compare the
   project's readers with.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from motion_files import SKELETON  # noqa: E402

OUT = ROOT / "tests" / "data" / "fbx"
FRAMES, FPS = 12, 30.0


def write_walk_bvh(path: Path, seed: int = 3) -> None:
    rng = np.random.default_rng(seed)
    children = {}
    for name, parent, _ in SKELETON:
        children.setdefault(parent, []).append(name)
    offset = {n: o for n, _, o in SKELETON}
    lines = ["HIERARCHY"]

    def joint(name, depth):
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if depth == 0 else 'JOINT'} {name}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {offset[name][0]:.6f} {offset[name][1]:.6f} {offset[name][2]:.6f}")
        chans = "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if depth == 0 else \
            "3 Zrotation Xrotation Yrotation"
        lines.append(f"{pad}  CHANNELS {chans}")
        kids = children.get(name, [])
        for c in kids:
            joint(c, depth + 1)
        if not kids:
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET 0.000000 5.000000 0.000000", pad + "  }"])
        lines.append(pad + "}")

    joint("Hips", 0)
    lines += ["MOTION", f"Frames: {FRAMES}", f"Frame Time: {1.0 / FPS:.8f}"]
    for f in range(FRAMES):
        vals = [3.0 * math.sin(f / 3.0), 95.0 + 2.0 * math.cos(f / 2.0), 4.0 * f]
        for name, _, _ in SKELETON:
            vals += list(rng.uniform(-35.0, 35.0, 3))
        lines.append(" ".join(f"{v:.6f}" for v in vals))
    path.write_text("\n".join(lines) + "\n")


def write_root_bone_bvh(walk: Path, path: Path) -> None:
    """``walk.bvh`` under a game rig's 'root' bone: a ROOT that walks and turns, the hips (with
    their own position channels) its only child."""
    lines = walk.read_text().splitlines()
    motion = lines.index("MOTION")
    head = ["HIERARCHY", "ROOT root", "{", "  OFFSET 0.000000 0.000000 0.000000",
            "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
    body = ["  " + ln.replace("ROOT Hips", "JOINT Hips") for ln in lines[1:motion]] + ["}"]
    frames = []
    for f, row in enumerate(lines[motion + 3:]):
        root = [10.0 * f, 0.0, -6.0 * f, 0.0, 0.0, 12.0 * f]  # walks and turns about Y (the last channel)
        frames.append(" ".join(f"{v:.6f}" for v in root) + " " + row)
    path.write_text("\n".join(head + body + lines[motion:motion + 3] + frames) + "\n")


def dump_bvh_import(bpy, bvh: Path) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_anim.bvh(filepath=str(bvh), global_scale=0.01, rotate_mode="NATIVE", axis_forward="-Z",
                            axis_up="Y", update_scene_fps=True, update_scene_duration=True)
    arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    names, heads = blender_heads(bpy, arm, range(1, FRAMES + 1))
    np.savez(bvh.with_suffix(".blender.npz"), names=np.array(names), heads=heads,
             fps=np.float64(bpy.context.scene.render.fps / bpy.context.scene.render.fps_base))
    print(f"{bvh.name}: {len(names)} bones")


def blender_heads(bpy, armature, frames: range) -> tuple[list[str], np.ndarray]:
    names = [b.name for b in armature.pose.bones]
    out = np.zeros((len(frames), len(names), 3))
    for k, f in enumerate(frames):
        bpy.context.scene.frame_set(f)
        M = np.array(armature.matrix_world)
        for j, b in enumerate(armature.pose.bones):
            h = np.array(b.head)
            out[k, j] = M[:3, :3] @ h + M[:3, 3]
    return names, out


def dump_import(bpy, fbx: Path) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.fbx(filepath=str(fbx), automatic_bone_orientation=False, ignore_leaf_bones=False)
    arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    act = arm.animation_data.action
    f0, f1 = (int(round(v)) for v in act.frame_range)
    names, heads = blender_heads(bpy, arm, range(f0, f1 + 1))
    np.savez(fbx.with_suffix(".blender.npz"), names=np.array(names), heads=heads,
             fps=np.float64(bpy.context.scene.render.fps / bpy.context.scene.render.fps_base))
    print(f"{fbx.name}: {len(names)} bones, frames {f0}-{f1}")


def main() -> None:
    import bpy

    sys.path.insert(0, str(ROOT / "tests"))
    from fbx_files import write_joint_orient_fbx

    OUT.mkdir(parents=True, exist_ok=True)
    bvh = OUT / "walk.bvh"
    write_walk_bvh(bvh)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_anim.bvh(filepath=str(bvh), global_scale=0.01, rotate_mode="NATIVE", axis_forward="-Z",
                            axis_up="Y", update_scene_fps=True, update_scene_duration=True)
    arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = 1, FRAMES
    # a small mesh skinned to the armature's root: FBX then keeps the rest pose in a bind pose (the
    # models' own values are the pose of the frame exported at, here a walking frame) and glTF keeps
    # the joints in a skin
    bpy.ops.mesh.primitive_cube_add(size=0.05, location=(0.0, 0.0, 0.95))
    cube = bpy.context.active_object
    mod = cube.modifiers.new("Armature", "ARMATURE")
    mod.object = arm
    cube.parent = arm
    group = cube.vertex_groups.new(name=arm.data.bones[0].name)
    group.add(list(range(len(cube.data.vertices))), 1.0, "REPLACE")
    bpy.context.scene.frame_set(5)
    bpy.ops.export_scene.fbx(filepath=str(OUT / "blender_walk.fbx"), object_types={"ARMATURE", "MESH"},
                             add_leaf_bones=False, bake_anim=True, bake_anim_use_all_actions=False,
                             bake_anim_use_nla_strips=False, bake_anim_simplify_factor=0.0,
                             axis_forward="-Z", axis_up="Y")
    bpy.ops.export_scene.gltf(filepath=str(OUT / "blender_walk.glb"), export_format="GLB", export_animations=True,
                              export_yup=True)
    write_joint_orient_fbx(OUT / "joint_orient.fbx")
    for fbx in (OUT / "blender_walk.fbx", OUT / "joint_orient.fbx"):
        dump_import(bpy, fbx)
    write_root_bone_bvh(bvh, OUT / "root_bone.bvh")
    dump_bvh_import(bpy, OUT / "root_bone.bvh")


if __name__ == "__main__":
    main()
