"""A URDF or MJCF file read once: its pytorch-kinematics chain, link meshes and a MuJoCo-ready XML.

Both formats end up in the same three forms, so everything downstream (FK, point clouds, simulation)
treats a user's model exactly like a built-in one. A file that holds more than the hand (an arm, a body, a
second hand) is cut to the subtree below the hand's root link first, so the rest is never loaded.
"""

from __future__ import annotations

import copy
import io
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import mujoco
import pytorch_kinematics as pk
import trimesh
import yourdfpy

from lerobot_opfa.hands.geometry import mjcf_link_meshes, resolve_urdf_mesh, urdf_link_meshes

# Least mass (kg) and inertia (kg m^2) of a URDF link in simulation, far below any real link's: MuJoCo
# refuses a moving body without mass, and vendors' URDFs have massless links (genesis-world's Shadow hand).
BOUND_MASS, BOUND_INERTIA = 1e-5, 1e-10


class ModelFileError(ValueError):
    """A model file that is missing or does not parse."""


@dataclass
class ModelFile:
    path: Path
    chain: pk.Chain
    link_meshes: dict[str, trimesh.Trimesh]
    mujoco_xml: str
    mujoco_assets: dict[str, bytes]

    @property
    def joint_names(self) -> list[str]:
        return self.chain.get_joint_parameter_names()

    @property
    def link_names(self) -> list[str]:
        return self.chain.get_link_names()


def load_model_file(path: Path, root: str | None = None) -> ModelFile:
    """The model in `path`, or only the subtree below its link or body `root`, whose frame becomes the
    model's root frame."""
    if not path.is_file():
        raise ModelFileError(f"{path}: model file not found")
    try:
        return _load_urdf(path, root) if path.suffix.lower() == ".urdf" else _load_mjcf(path, root)
    except ModelFileError:
        raise
    except Exception as err:  # parsers raise many types; all mean "this file is not a usable model"
        raise ModelFileError(
            f"{path}: does not parse as {'URDF' if path.suffix == '.urdf' else 'MJCF'}: {err}"
        ) from err


def _load_urdf(path: Path, root: str | None) -> ModelFile:
    text = path.read_bytes() if root is None else _urdf_subtree(path, root)
    robot = yourdfpy.URDF.load(io.BytesIO(text), build_scene_graph=False, load_meshes=False)
    chain = pk.build_chain_from_urdf(text)
    xml, assets = _urdf_for_mujoco(text, path)
    return ModelFile(path, chain, urdf_link_meshes(robot, path), xml, assets)


def _urdf_subtree(path: Path, root: str) -> bytes:
    """The URDF cut to `root` and the links and joints below it; every other element that names a link
    or joint left out (transmissions, simulator extensions) goes with them."""
    tree = ET.parse(path).getroot()
    links = {link.get("name") for link in tree.findall("link")}
    joints = {joint.get("name") for joint in tree.findall("joint")}
    if root not in links:
        raise ModelFileError(f"{path}: no link '{root}' (the spec's `root`); its links are {sorted(links)}")
    children: dict[str, list[ET.Element]] = {}
    for joint in tree.findall("joint"):
        children.setdefault(joint.find("parent").get("link"), []).append(joint)
    kept_links, kept_joints, pending = {root}, set(), [root]
    while pending:
        for joint in children.get(pending.pop(), []):
            kept_joints.add(joint.get("name"))
            kept_links.add(joint.find("child").get("link"))
            pending.append(joint.find("child").get("link"))
    for element in list(tree):
        keep = {"link": kept_links, "joint": kept_joints}.get(element.tag)
        if (
            keep is not None
            and element.get("name") not in keep
            or element.tag not in ("link", "joint", "material")
        ):
            tree.remove(element)
    for joint in tree.findall("joint"):
        mimic = joint.find("mimic")
        if mimic is not None and mimic.get("joint") not in joints:
            # A mimic of a joint the file does not have (Alex's Psyonic hands mimic `index_q1` for
            # `Right_index_q1`) says nothing: the spec's `couplings` say how the joint moves.
            joint.remove(mimic)
        elif mimic is not None and mimic.get("joint") not in kept_joints:
            raise ModelFileError(
                f"{path}: joint '{joint.get('name')}' below '{root}' mimics '{mimic.get('joint')}', which is "
                "not below it; take a root above both"
            )
    return ET.tostring(tree, encoding="utf-8")


def _urdf_for_mujoco(text: bytes, path: Path) -> tuple[str, dict[str, bytes]]:
    """MuJoCo reads URDF itself, but strips mesh directories, does not know `package://` and fuses fixed
    links away. Give it every mesh as an STL asset and keep every link a body. A link with visual geometry
    and no collision geometry (CAD exports write only visuals) collides with its visuals: MuJoCo keeps
    URDF visuals out of contact, and a hand of visuals only went through the button it pressed."""
    root = ET.fromstring(text)
    for link in root.iter("link"):
        if link.find("collision") is None:
            for visual in link.findall("visual"):
                collision = ET.SubElement(link, "collision")
                collision.extend(copy.deepcopy(c) for c in visual if c.tag in ("origin", "geometry"))
    assets: dict[str, bytes] = {}
    names: dict[str, str] = {}  # a file used twice (a visual and its collision copy) is converted once
    for mesh in root.iter("mesh"):
        filename = mesh.get("filename")
        if filename not in names:
            names[filename] = f"{len(names)}_{Path(filename).stem}.stl"  # MuJoCo's messages name the asset
            assets[names[filename]] = _binary_stl(resolve_urdf_mesh(filename, path))
        mesh.set("filename", names[filename])
    for old in root.findall("mujoco"):
        root.remove(old)
    extension = ET.SubElement(root, "mujoco")
    ET.SubElement(
        extension, "compiler", fusestatic="false", discardvisual="false", balanceinertia="true",
        boundmass=str(BOUND_MASS), boundinertia=str(BOUND_INERTIA),
    )  # fmt: skip
    return ET.tostring(root, encoding="unicode"), assets


def _binary_stl(file: Path) -> bytes:
    """The mesh as binary STL, the one mesh format MuJoCo reads of those URDFs use: a binary STL file as it
    is (its triangle count fits its size), anything else (ASCII STL, DAE, OBJ, PLY) converted."""
    data = file.read_bytes()
    binary = len(data) >= 84 and len(data) == 84 + 50 * int.from_bytes(data[80:84], "little")
    if binary and file.suffix.lower() == ".stl":
        return data
    buffer = io.BytesIO()
    trimesh.load(file, force="mesh").export(buffer, file_type="stl")
    return buffer.getvalue()


class _JointTypes(dict):
    """pytorch-kinematics' joint-type map keyed by int: it looks types up with the `np.int32` a model
    holds, which mujoco>=4's enum keys do not match."""

    def __getitem__(self, key):
        return super().__getitem__(int(key))


def _load_mjcf(path: Path, root_body: str | None) -> ModelFile:
    root = ET.parse(path).getroot()
    if root.tag != "mujoco":
        include = f'<include file="{path.name}"/>'
        if root.find("worldbody") is None:  # bodies only: they go inside the wrapper's worldbody
            include = f"<worldbody>{include}</worldbody>"
        raise ModelFileError(
            f"{path}: a <{root.tag}> fragment, not a model (<mujoco>); name a wrapper file beside it in the "
            f'spec: <mujoco model="hand">{include}</mujoco> (with the fragment\'s <compiler meshdir> and '
            "<asset> if it needs them)"
        )
    if not isinstance(pk.mjcf.JOINT_TYPE_MAP, _JointTypes):
        pk.mjcf.JOINT_TYPE_MAP = _JointTypes({int(k): v for k, v in pk.mjcf.JOINT_TYPE_MAP.items()})
    xml = mujoco.MjSpec.from_file(str(path)).to_xml()  # includes resolved, defaults written out
    if root_body is not None:
        xml = _mjcf_subtree(xml, root_body, path)
    spec = mujoco.MjSpec.from_string(xml)
    assets = {}
    for mesh in spec.meshes:
        if mesh.file:
            file = (path.parent / (spec.meshdir or "") / mesh.file).resolve()
            assets[mesh.file] = file.read_bytes()
    model = mujoco.MjModel.from_xml_string(xml, assets)
    chain = pk.build_chain_from_mjcf(xml, assets=assets)
    return ModelFile(path, chain, mjcf_link_meshes(model), xml, assets)


def _mjcf_subtree(xml: str, root: str, path: Path) -> str:
    """The model cut to the body `root` and the bodies below it, `root` fixed at the world's origin.
    Actuators, tendons, equalities, contact pairs, sensors and keyframes go: they may name what was cut,
    and the simulated hand replaces the hand's own from its spec (`mujoco_model`)."""
    model = ET.fromstring(xml)
    worldbody = model.find("worldbody")
    parents = {child: parent for parent in worldbody.iter() for child in parent}
    body = next((b for b in worldbody.iter("body") if b.get("name") == root), None)
    if body is None:
        bodies = [b.get("name") for b in worldbody.iter("body")]
        raise ModelFileError(f"{path}: no body '{root}' (the spec's `root`); its bodies are {bodies}")
    ancestor = parents.get(body)
    while body.get("childclass") is None and ancestor is not None and ancestor is not worldbody:
        if ancestor.get("childclass") is not None:
            body.set("childclass", ancestor.get("childclass"))
        ancestor = parents.get(ancestor)
    for key in ("pos", "quat", "euler", "axisangle", "xyaxes", "zaxis"):
        body.attrib.pop(key, None)
    for joint in body.findall("joint") + body.findall("freejoint"):  # what moved it in the model it left
        body.remove(joint)
    worldbody.clear()
    worldbody.append(body)
    for tag in ("actuator", "tendon", "equality", "contact", "sensor", "keyframe"):
        for section in model.findall(tag):
            model.remove(section)
    used = {geom.get("mesh") for geom in body.iter("geom")}
    for asset in model.findall("asset"):
        for mesh in asset.findall("mesh"):
            if mesh.get("name") not in used:
                asset.remove(mesh)
    return ET.tostring(model, encoding="unicode")
