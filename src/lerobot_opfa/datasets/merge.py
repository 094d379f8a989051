"""`lerobot-opfa dataset merge`: per-robot LeRobotDatasets -> one cross-embodiment LeRobotDataset (v3).

Hands have different joint counts, so the merged state/action use one layout for all: the body entries,
then per hand slot the universal joints (zero where a hand has none) and, when a GaLR is given, the latent z
of that hand, computed once here so that training in GaLR space costs what a raw-joint step costs
(`layout.merged_names`). `observation.embodiment` holds each slot's hand index (its feature names list the
hands). Robots co-train when they share their body entries and their number of hands, whatever hands they
hold, at whatever rates they were recorded: inputs at another rate than the merge's are resampled by
timestamp (`resample`). Point clouds stay flattened (N*3,) so LeRobot's own dataset tools keep working.
"""

from __future__ import annotations

import difflib
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils.constants import ACTION, OBS_STATE
from tqdm import tqdm

from lerobot_opfa.datasets.cameras import (
    CAMERA_DTYPES,
    Camera,
    camera_features,
    camera_frame,
    parse_camera_map,
    plan_cameras,
)
from lerobot_opfa.datasets.io import check_dataset_folder, check_outside_inputs, new_dataset, read_columns
from lerobot_opfa.datasets.joint_map import HANDS_SEPARATOR, JointMap
from lerobot_opfa.datasets.layout import (
    LATENT_ROBOT_TYPE,
    OPFA_META_FILE,
    DatasetLayout,
    feature_names,
    hand_entry,
    merged_names,
    opfa_record,
    read_layout,
)
from lerobot_opfa.datasets.resample import resampling
from lerobot_opfa.datasets.statistics import column_statistics, noise_floor, raw_noise, write_statistics
from lerobot_opfa.features import OBS_EMBODIMENT, OBS_POINTCLOUD, column_embodiments
from lerobot_opfa.galr import checkpoints
from lerobot_opfa.galr.frozen import (
    encode_joints,
    encode_universal,
    galr_fingerprint,
    known_hand_refs,
    load_galr,
)
from lerobot_opfa.hands.registry import load_hand, load_spec
from lerobot_opfa.hands.universal import UNIVERSAL_JOINT_NAMES

if TYPE_CHECKING:
    from lerobot_opfa.hands.model import HandModel

logger = logging.getLogger(__name__)

BOOKKEEPING = ("timestamp", "frame_index", "episode_index", "index", "task_index")
NUMERIC = ("float32", "float64", "int64", "int32", "bool")


@dataclass
class _Input:
    root: Path
    meta: LeRobotDatasetMetadata
    layout: DatasetLayout


def _open(root: Path, hands: list[str] | None, joint_maps: list[JointMap], bound: JointMap | None) -> _Input:
    """An input, read through the map bound to it, else the one map of `joint_maps` whose entries it has."""
    check_dataset_folder(root)
    meta = LeRobotDatasetMetadata(f"local/{root.name}", root=root)
    if meta.robot_type == LATENT_ROBOT_TYPE:
        raise ValueError(
            f"{root} is a latent dataset (`policy latent-dataset`); merge the datasets it came from"
        )
    names = set(feature_names(meta.features, OBS_STATE))
    fitting = (
        [bound] if bound is not None else [m for m in joint_maps if set(m.key_joints(OBS_STATE)) <= names]
    )
    if len(fitting) > 1:
        raise ValueError(
            f"{root}: several joint maps fit its entries ({', '.join(m.source for m in fitting)}); bind one "
            f"to it: --joint-maps {root}=MAP"
        )
    joint_map = fitting[0] if fitting else None
    try:
        layout = read_layout(meta.features, meta.robot_type, root, hands, joint_map)
    except ValueError:
        near = min(joint_maps, key=lambda m: len(_absent(m, names)), default=None) if not fitting else None
        if near is None or len(_absent(near, names)) > len(near.key_joints(OBS_STATE)) / 2:
            raise
        raise ValueError(
            f"{root}: joint map {near.source} would fit it, but for {_absent(near, names, say=True)}; "
            "correct the map's entries"
        ) from None
    if layout.kind != "native":
        raise ValueError(f"{root} is already a merged dataset; merge the per-hand datasets it came from")
    if layout.action_body_names is not None:
        raise ValueError(
            f"{root}: its action's body entries {layout.action_body_names} are not its state's "
            f"{layout.wrist_names}; a merge holds one body for both: train on it alone (--policy.joint_map)"
        )
    return _Input(root, meta, layout)


def _absent(joint_map: JointMap, names: set[str], say: bool = False) -> list[str] | str:
    """The state entries of `joint_map` missing from `names`; with `say`, each with the closest entry there
    is, as one phrase."""
    absent = sorted(set(joint_map.key_joints(OBS_STATE)) - names)
    if not say:
        return absent
    said = []
    for entry in absent:
        near = difflib.get_close_matches(entry, sorted(names), n=1)
        said.append(f"entry {entry!r}" + (f" (did you mean {near[0]!r}?)" if near else " (in no entry)"))
    return ", ".join(said)


def _passthrough(inputs: list[_Input]) -> dict[str, dict]:
    """Numeric features every input has (besides state and action); inputs that disagree on one's dtype
    or shape (clouds of different sizes, say) are an error, not a feature silently left out."""
    first = inputs[0].meta.features
    common = {}
    for key, feature in first.items():
        if key in (OBS_STATE, ACTION, *BOOKKEEPING) or feature["dtype"] not in NUMERIC:
            continue
        if not all(key in i.meta.features for i in inputs):
            continue
        kinds = {
            i.root: (i.meta.features[key]["dtype"], tuple(i.meta.features[key]["shape"])) for i in inputs
        }
        if len(set(kinds.values())) > 1:
            shapes = ", ".join(f"{root}: {dtype} {shape}" for root, (dtype, shape) in kinds.items())
            raise ValueError(
                f"the inputs disagree on feature '{key}' ({shapes}); record them alike (the same --n-points "
                "for point clouds) to merge them"
            )
        common[key] = {**feature, "shape": tuple(feature["shape"])}
    return common


def _maps_per_input(roots: list[Path], joint_maps: list[Path | str]) -> tuple[dict[Path, JointMap], list]:
    """The maps bound to an input (`INPUT=MAP`, for robots whose entries are named alike) and the others
    (`MAP`: each input takes the one whose entries it has)."""
    bound, free = {}, []
    for item in map(str, joint_maps):
        if Path(item).is_file() or "=" not in item:
            free.append(JointMap.load(item))
            continue
        split = next((i for i, c in enumerate(item) if c == "=" and Path(item[:i]).resolve() in roots), None)
        if split is None:
            raise ValueError(
                f"--joint-maps {item}: not a map file, nor INPUT=MAP with INPUT one of --inputs "
                f"({', '.join(map(str, roots))})"
            )
        root = Path(item[:split]).resolve()
        if root in bound:
            raise ValueError(f"--joint-maps binds two maps to the input {root}; give it one")
        bound[root] = JointMap.load(item[split + 1 :])
    return bound, free


def merge_datasets(
    inputs: list[Path | str],
    output: Path | str,
    galr_path: str | None = None,
    repo_id: str = "local/opfa_merged",
    overwrite: bool = False,
    joint_maps: list[Path | str] = (),
    fps: int | None = None,
    camera_map: list[str] = (),
) -> Path:
    """Writes the merged dataset to `output` atomically and returns its path. `joint_maps`: map files for
    inputs whose entries are not named after their hand's joints; each input takes the one whose entries
    it has, or the one bound to it as `INPUT=MAP`. `fps`: the merge's rate (default: the lowest of the
    inputs'). `camera_map`: `ROLE=KEY` items naming which camera of each input is which (`cameras`)."""
    galr = None
    hands = None
    if galr_path is not None:
        galr = load_galr(str(galr_path))
        hands = known_hand_refs(galr)
    roots = check_outside_inputs(inputs, output)
    bound, maps = _maps_per_input(roots, joint_maps)
    opened = [_open(root, hands, maps, bound.get(root)) for root in roots]
    unused = [m for m in maps if not any(i.layout.joint_maps[0].source == m.source for i in opened)]
    if unused:
        names = {i.root: set(feature_names(i.meta.features, OBS_STATE)) for i in opened}
        closest = {m.source: min(names, key=lambda root: len(_absent(m, names[root]))) for m in unused}
        raise ValueError(
            "; ".join(
                f"joint map {m.source} fits none of the inputs: in {closest[m.source]}, the closest, "
                f"{_absent(m, names[closest[m.source]], say=True)}"
                for m in unused
            )
        )
    wrist, sides = opened[0].layout.wrist_names, _sides(opened[0])
    if fps is not None and fps < 1:
        raise ValueError(f"--fps: a positive rate, not {fps}")
    fps = fps or min(i.meta.fps for i in opened)
    for i in opened:
        if i.layout.wrist_names != wrist:
            armed = {j.root: j.layout.joint_maps[0].armed for j in (opened[0], i)}
            unarmed = ", ".join(str(root) for root, has_arm in armed.items() if not has_arm)
            hint = (
                f"; {unarmed} names no arm: its map's `arm` reads its body as the wrist pose the other's is "
                "(an arm spec, `floating` for the simulator's wrist entries, `end_effector` for LeRobot's "
                "ee.* entries), or train it alone"
                if len(set(armed.values())) > 1
                else ""
            )
            raise ValueError(
                f"inputs disagree: {i.root} has body entries {i.layout.wrist_names}, {opened[0].root} has "
                f"{wrist}{hint}"
            )
        if _sides(i) != sides:
            raise ValueError(
                f"inputs disagree: {i.root} has hands on sides {_sides(i)}, {opened[0].root} on {sides}; "
                "a merge holds robots with the same hand slots"
            )
    embodiments = list(dict.fromkeys(h for i in opened for h in _slot_hands(i)))
    if galr is not None:
        unknown = [h for h in embodiments if h not in galr.config.hand_names]
        if unknown:
            raise ValueError(
                f"hand(s) {unknown} are not in the GaLR registry of {galr_path} ({galr.config.hand_names}); "
                f"add them with `lerobot-opfa galr pretrain --init {galr_path} --hands +{','.join(unknown)}`"
            )
    latent_dim = galr.config.latent_dim if galr is not None else 0
    names = merged_names(wrist, sides, latent_dim)
    extra = _passthrough(opened)
    cameras = plan_cameras({i.root: i.meta.features for i in opened}, parse_camera_map(list(camera_map)))
    sources = {key for camera in cameras for key in camera.sources.values() if key is not None}
    _check_visual(opened, [*extra, *sources])
    kept = {OBS_STATE, ACTION, *BOOKKEEPING, *extra, *sources}
    dropped = sorted({k for i in opened for k in i.meta.features} - kept)
    if dropped:
        logger.warning("features not shared by all inputs are left out: %s", dropped)
    features = {
        OBS_STATE: {"dtype": "float32", "shape": (len(names),), "names": names},
        ACTION: {"dtype": "float32", "shape": (len(names),), "names": names},
        OBS_EMBODIMENT: {"dtype": "int64", "shape": (len(sides),), "names": embodiments},
        **extra,
        **camera_features(cameras),
    }
    for source in opened:
        _check_limits(source, galr)
    total = sum(i.meta.total_frames for i in opened)
    videos = any(camera.feature["dtype"] == "video" for camera in cameras)
    create = dict(repo_id=repo_id, fps=fps, features=features, robot_type="opfa_merged", use_videos=videos)
    with new_dataset(output, overwrite, **create) as merged:
        partial = merged.root
        with tqdm(total=total, desc="merging", unit="frame") as progress:
            for source in opened:
                _append(merged, source, embodiments, galr, list(extra), cameras, progress, fps)
        merged.finalize()
        write_statistics(partial, _statistics(partial, embodiments, galr, len(wrist), len(sides)))
        refs = {h: r for i in opened for h, r in zip(i.layout.embodiments, i.layout.hand_refs, strict=True)}
        user_hands = {name: hand_entry(load_spec(ref)) for name, ref in refs.items() if ref != name}
        robots = list(dict.fromkeys(tuple(embodiments.index(h) for h in _slot_hands(i)) for i in opened))
        meta = {
            "embodiments": embodiments,
            **({"robots": [list(r) for r in robots]} if len(sides) > 1 else {}),
            "inputs": [str(i.root) for i in opened],
            "input_fps": [i.meta.fps for i in opened],
            "camera_sources": {
                camera.key: {str(root): key for root, key in camera.sources.items()}
                for camera in cameras
                if set(camera.sources.values()) != {camera.key}
            },
            "latent_dim": latent_dim,
            "hands": user_hands,
            "joint_maps": _deployed_maps(opened),
        }
        if galr is not None:
            meta |= {"galr": checkpoints.record(galr_path), "galr_fingerprint": galr_fingerprint(galr)}
        calibration = _clouds_calibration(opened)
        if calibration is not None:
            meta["cameras"] = calibration
        (partial / OPFA_META_FILE).write_text(json.dumps(meta, indent=2))
    logger.info("merged %d frames of %s into %s", total, embodiments, output)
    return Path(output)


def _statistics(
    root: Path, embodiments: list[str], galr, n_wrist: int, slots: int
) -> dict[str, torch.Tensor]:
    """Per-embodiment statistics of the merged state and action (each entry by its slot's hand), and the
    noise floor of the cached z: what the opfa processors fit their normalisation to
    (`statistics.STATS_FILE`)."""
    frames = read_columns(root, [OBS_STATE, ACTION, OBS_EMBODIMENT])
    ids = torch.tensor(frames[OBS_EMBODIMENT], dtype=torch.long).view(len(frames[OBS_STATE]), slots)
    width = (frames[OBS_STATE].shape[-1] - n_wrist) // slots
    columns = column_embodiments(ids, [n_wrist] + [width] * slots)
    out = {}
    for key in (OBS_STATE, ACTION):
        stats = column_statistics(torch.tensor(frames[key], dtype=torch.float32), columns, len(embodiments))
        out |= {f"{key}.{name}": value for name, value in stats.items()}
    if galr is not None:
        state = torch.tensor(frames[OBS_STATE], dtype=torch.float32)
        parts = state[:, n_wrist:].reshape(len(state), slots, width)  # each slot's hand as a frame of its own
        hands = torch.cat([state[:, :n_wrist].repeat(slots, 1), parts.transpose(0, 1).reshape(-1, width)], 1)
        out["latent_noise_floor"] = _latent_noise_floor(galr, embodiments, hands, ids.T.reshape(-1), n_wrist)
    return out


def _latent_noise_floor(galr, embodiments: list[str], state: torch.Tensor, ids: torch.Tensor, n_wrist: int):
    """(d,): what joint noise moves each entry of z by, over all hands' frames (`statistics.noise_floor`)."""
    joints = n_wrist + len(UNIVERSAL_JOINT_NAMES)

    def encode(rows: torch.Tensor, kept: torch.Tensor) -> torch.Tensor:
        return encode_universal(galr, embodiments, rows[:, n_wrist:], ids[kept])

    noise = raw_noise(n_wrist, list(UNIVERSAL_JOINT_NAMES))
    pooled = torch.ones(galr.config.latent_dim, dtype=torch.bool)
    floor = noise_floor(encode, state[:, :joints], state[:, joints:], ids, noise, len(embodiments), pooled)
    return floor[0]


def _sides(source: _Input) -> list[str | None]:
    """The sides of an input's hand slots ([None]: a one-handed robot)."""
    return [slot.side for slot in source.layout.joint_maps[0].slots]


def _slot_hands(source: _Input) -> list[str]:
    """The hand of each of an input's slots."""
    return [source.layout.embodiments[e] for e in source.layout.robots[0]]


def _deployed_maps(opened: list[_Input]) -> dict[str, dict]:
    """Per hand, the joint map its robot's vectors were merged with: what a policy trained on the merged
    dataset saves, to speak that robot's entries when deployed."""
    maps = {}
    for source in opened:
        joint_map, robot = source.layout.joint_maps[0], HANDS_SEPARATOR.join(_slot_hands(source))
        first = maps.setdefault(robot, joint_map.to_dict())
        if first != joint_map.to_dict():
            logger.warning(
                "inputs of hand(s) '%s' lay out their entries differently; a policy trained on this dataset "
                "drives the robot of the first (%s)",
                robot,
                opened[0].root,
            )
    return maps


def _hands(source: _Input, galr) -> list[HandModel]:
    """The hand model of each of an input's slots (the GaLR's, where one is given)."""
    refs = [source.layout.hand_refs[e] for e in source.layout.robots[0]]
    return [
        load_hand(r) if galr is None else galr.hand(h)[0]
        for r, h in zip(refs, _slot_hands(source), strict=True)
    ]


def _check_limits(source: _Input, galr) -> None:
    """Every state and action frame of the input finite and within its hand's joint limits, each joint's
    commands in the sense of its states (before anything is written: latents of values out of range would be
    cached without a word)."""
    hands, joint_map = _hands(source, galr), source.layout.joint_maps[0]
    columns = read_columns(source.root, [OBS_STATE, ACTION, "episode_index"])
    episodes = torch.tensor(columns.pop("episode_index"))
    for key, values in columns.items():
        body, qs = joint_map.split(torch.tensor(values, dtype=torch.float64), key)
        bad = ~body.isfinite()
        if bad.any():
            entry = joint_map.body_names(key)[int(bad.any(0).nonzero()[0])]
            raise ValueError(
                f"{source.root}: {key} is not finite (NaN or inf) in {int(bad.any(1).sum())} of {len(body)} "
                f"frames, first in entry '{entry}'"
            )
        for hand, q, slot in zip(hands, qs, joint_map.slots, strict=True):
            side = f", {slot.side} hand" if slot.side else ""
            hand.check_within_limits(q, f"{source.root} ({key}, through {joint_map.source}{side})")
        where = f"{source.root} ({key}, through {joint_map.source})"
        if joint_map.armed:
            joint_map.check_arms(torch.tensor(values), key, where)
        joint_map.check_spans(torch.tensor(values), key, [(hand.lower, hand.upper) for hand in hands])
    joint_map.check_senses(torch.tensor(columns[OBS_STATE]), torch.tensor(columns[ACTION]), episodes)


def _check_visual(inputs: list[_Input], kept: list[str]) -> None:
    """Inputs with cameras or clouds that share none would make a merge with nothing to see: refused."""
    seen = {
        i.root: [k for k, f in i.meta.features.items() if f["dtype"] in CAMERA_DTYPES or k == OBS_POINTCLOUD]
        for i in inputs
    }
    if any(seen.values()) and not any(k in kept for keys in seen.values() for k in keys):
        found = "; ".join(f"{root}: {', '.join(keys) or 'none'}" for root, keys in seen.items())
        raise ValueError(
            f"the inputs share no camera or point cloud ({found}): their merge would hold none to train on; "
            "merge inputs recorded with the same camera key"
        )


def _clouds_calibration(inputs: list[_Input]) -> dict | None:
    """The depth cameras the inputs' clouds were made with (`dataset clouds`), kept when all share one, so
    that a policy trained on the merge takes a robot's depth frames through the same step."""
    recorded = [opfa_record(i.root).get("cameras") for i in inputs]
    if all(r is None for r in recorded):
        return None
    if all(r == recorded[0] for r in recorded):
        return recorded[0]
    logger.warning(
        "the inputs' clouds were made with different camera calibrations (or some without one): the merged "
        "dataset records none, so a policy trained on it takes point clouds, not depth frames"
    )
    return None


def _append(
    merged, source: _Input, embodiments, galr, extra: list[str], cameras: list[Camera], progress, fps: int
) -> None:
    """Writes the input's episodes into the merged dataset, at its rate `fps`."""
    hands, joint_map = _hands(source, galr), source.layout.joint_maps[0]
    columns = read_columns(source.root, [OBS_STATE, ACTION, *extra, *BOOKKEEPING])
    tasks = {int(row.task_index): task for task, row in source.meta.tasks.iterrows()}
    embodiment = np.array([embodiments.index(hand.name) for hand in hands], np.int64)
    decode = any(camera.sources[source.root] is not None for camera in cameras)
    if decode:  # decoded frame by frame, as LeRobot serves them
        frames = LeRobotDataset(f"local/{source.root.name}", root=source.root)
        position = {int(index): i for i, index in enumerate(frames.hf_dataset["index"])}

    def to_layout(values: np.ndarray, key: str) -> np.ndarray:
        body, qs = joint_map.split(torch.tensor(values, dtype=torch.float64), key)
        parts = [body.numpy()]
        for hand, q in zip(hands, qs, strict=True):
            parts.append(hand.to_universal(q.float()).cpu().numpy())
            if galr is not None:
                parts.append(encode_joints(galr, hand.name, q.float()).cpu().numpy())
        return np.concatenate(parts, axis=1).astype(np.float32)

    episodes = columns["episode_index"]
    for episode in dict.fromkeys(episodes.tolist()):
        rows = np.flatnonzero(episodes == episode)
        rows = rows[np.argsort(columns["frame_index"][rows])]
        entries = {key: columns[key][rows] for key in (OBS_STATE, ACTION)}
        picks = rows  # the recorded frame each written frame takes its other features from
        if source.meta.fps != fps:
            where = f"{source.root}, episode {episode}"
            timing = resampling(columns["timestamp"][rows], source.meta.fps, fps, where)
            entries = {key: timing.interpolate(values) for key, values in entries.items()}
            picks = rows[timing.nearest]
        state, action = to_layout(entries[OBS_STATE], OBS_STATE), to_layout(entries[ACTION], ACTION)
        for j, row in enumerate(picks):
            frame = {OBS_STATE: state[j], ACTION: action[j], OBS_EMBODIMENT: embodiment}
            for key in extra:
                dtype = merged.meta.features[key]["dtype"]
                frame[key] = np.asarray(columns[key][row], dtype=dtype).reshape(
                    merged.meta.features[key]["shape"]
                )
            item = frames[position[int(columns["index"][row])]] if decode else None
            frame |= camera_frame(cameras, source.root, item)
            frame["task"] = tasks[int(columns["task_index"][row])]
            merged.add_frame(frame)
        merged.save_episode()
        progress.update(len(rows))
