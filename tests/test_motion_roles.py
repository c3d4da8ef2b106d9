"""The joint-role table (reconstruct.motion.roles) on the skeletons it names."""

import numpy as np

from reconstruct.body.smpl_backend import BONE_LABELS, SMPL_JOINT_NAMES
from reconstruct.motion.roles import (
    ROLE_TABLE,
    body_naming,
    find_roles,
    match_spines,
    normalise,
)

LIMB_ROLES = [r for r in ROLE_TABLE if r not in ("toe_l", "toe_r")]

MIXAMO = ["mixamorig:Hips", "mixamorig:Spine", "mixamorig:Spine1", "mixamorig:Spine2", "mixamorig:Neck",
          "mixamorig:Head", "mixamorig:HeadTop_End", "mixamorig:LeftShoulder", "mixamorig:LeftArm",
          "mixamorig:LeftForeArm", "mixamorig:LeftHand", "mixamorig:LeftHandIndex1", "mixamorig:RightShoulder",
          "mixamorig:RightArm", "mixamorig:RightForeArm", "mixamorig:RightHand", "mixamorig:LeftUpLeg",
          "mixamorig:LeftLeg", "mixamorig:LeftFoot", "mixamorig:LeftToeBase", "mixamorig:RightUpLeg",
          "mixamorig:RightLeg", "mixamorig:RightFoot", "mixamorig:RightToeBase"]
CMU = ["Hips", "LHipJoint", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase", "RHipJoint", "RightUpLeg", "RightLeg",
       "RightFoot", "RightToeBase", "LowerBack", "Spine", "Spine1", "Neck", "Neck1", "Head", "LeftShoulder", "LeftArm",
       "LeftForeArm", "LeftHand", "LeftFingerBase", "LeftHandIndex1", "LThumb", "RightShoulder", "RightArm",
       "RightForeArm", "RightHand", "RightFingerBase", "RightHandIndex1", "RThumb"]


def test_normalise():
    assert normalise("mixamorig:LeftUpLeg") == "leftupleg"
    assert normalise("Left_Up-Leg") == "leftupleg"


def test_mixamo_and_cmu_names():
    for names in (MIXAMO, CMU):
        roles = find_roles(names, "bvh")
        assert set(LIMB_ROLES) <= set(roles), set(LIMB_ROLES) - set(roles)
        strip = [normalise(n) for n in names]
        assert strip[roles["clavicle_l"]] == "leftshoulder"  # BVH's LeftShoulder is the clavicle
        assert strip[roles["upperarm_l"]] == "leftarm"
        assert strip[roles["lowerleg_r"]] == "rightleg"
        assert strip[roles["toe_l"]] == "lefttoebase"
        assert strip[roles["neck"]] == "neck"


def test_smpl_names_and_bodies():
    smpl = find_roles(list(SMPL_JOINT_NAMES), "smpl")
    assert SMPL_JOINT_NAMES[smpl["upperarm_l"]] == "left_shoulder"  # SMPL's shoulder joint is the upper arm
    assert SMPL_JOINT_NAMES[smpl["clavicle_r"]] == "right_collar"
    assert SMPL_JOINT_NAMES[smpl["toe_l"]] == "left_foot"
    assert set(ROLE_TABLE) <= set(smpl)
    body = find_roles(list(BONE_LABELS), body_naming(list(BONE_LABELS)))
    assert body_naming(list(BONE_LABELS)) == "smpl_body"
    assert {k: BONE_LABELS[v] for k, v in body.items()}["upperarm_l"] == "upperarm.L"


def test_anny_roles(anny_body):
    labels = list(anny_body.bone_labels)
    assert body_naming(labels) == "anny"
    roles = find_roles(labels, "anny")
    assert set(LIMB_ROLES) <= set(roles)
    assert labels[roles["hips"]] == "root" and labels[roles["upperleg_r"]] == "upperleg01.R"


def test_spine_matching_by_height_fraction():
    # a two-joint spine against a five-bone spine: each goes to the nearest fraction, in order
    pairs = match_spines([10, 11], np.array([0.22, 0.5]), [0, 1, 2, 3, 4], np.array([0.0, 0.13, 0.27, 0.41, 0.67]))
    assert [(s, b) for _, s, b in pairs] == [(10, 2), (11, 3)]
    # identical skeletons map one to one
    pairs = match_spines([5, 6, 7], np.array([0.2, 0.45, 0.6]), [1, 2, 3], np.array([0.2, 0.45, 0.6]))
    assert [(s, b) for _, s, b in pairs] == [(5, 1), (6, 2), (7, 3)]
