"""A user's mistakes with datasets, joint maps, merges and writers are refused in one line before any work,
and nothing is lost or left half-written (issue 42): concurrent writers, a full disk, LeRobot's own editing
tools, maps of the wrong hand or units, merges without a shared camera, maps bound to inputs."""

from __future__ import annotations

import errno
import gc
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.datasets.dataset_writer import DatasetWriter
from lerobot.utils.constants import ACTION, OBS_STATE
from test_policy import ENV, save_galr

from lerobot_opfa import cli
from lerobot_opfa.datasets.io import atomic_directory, new_dataset, read_columns
from lerobot_opfa.datasets.layout import OPFA_META_FILE, opfa_record, read_layout
from lerobot_opfa.datasets.synthetic import write_synthetic_dataset

EDIT_DATASET = Path(sys.executable).with_name("lerobot-edit-dataset")


def _siblings(output: Path) -> list[str]:
    return sorted(p.name for p in output.parent.iterdir() if p.name.startswith(f".{output.name}."))


def _one_line(capsys) -> str:
    """The error the CLI printed: its last line (above it only progress bars), with no traceback."""
    err = capsys.readouterr().err.strip()
    assert err.splitlines()[-1].startswith("error: ") and "Traceback" not in err, err
    return err.splitlines()[-1]


# --- writers ------------------------------------------------------------------------------------------


def test_an_output_that_appears_while_writing_is_kept_not_replaced(tmp_path):
    """Two runs to one output without --overwrite: the one that finishes second is refused, and the first's
    dataset stays whole."""
    output = tmp_path / "merged"
    create = dict(repo_id="local/merged", fps=10, features={}, robot_type="umi", use_videos=False)
    with pytest.raises(FileExistsError, match="appeared while this run was writing it") as error:
        with new_dataset(output, **create):
            # the other run, in another process, finishes first: its partial folder becomes the output
            write_synthetic_dataset(tmp_path / "other", "umi", episodes=1, frames=3, n_points=4)
            (tmp_path / "other").rename(output)
    assert "\n" not in str(error.value)
    assert LeRobotDatasetMetadata("local/merged", root=output).total_episodes == 1
    assert read_columns(output, [OBS_STATE])[OBS_STATE].shape == (3, 7), "the first run's dataset, whole"
    assert _siblings(output) == []
    with pytest.raises(FileExistsError, match="appeared while"), atomic_directory(tmp_path / "x") as partial:
        partial.mkdir()
        (tmp_path / "x").mkdir()
        (tmp_path / "x" / "kept").write_text("first")
    assert (tmp_path / "x" / "kept").read_text() == "first"


def test_a_full_disk_leaves_nothing_behind_and_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    """ENOSPC when LeRobot's writer closes its data file: its retried `finalize` fails again; the
    metadata's buffered episodes must not be flushed into the deleted partial folder afterwards."""

    def disk_full(self):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(DatasetWriter, "close_writer", disk_full)
    output = tmp_path / "demos"
    assert cli.main(["dataset", "synthetic", "--hand", "umi", "--output", str(output), "--episodes", "2",
                     "--frames", "3", "--n-points", "4"]) == 2  # fmt: skip
    err = _one_line(capsys)
    assert f"{output} was not written: the disk is full" in err
    gc.collect()  # LeRobot flushes what its metadata buffered when the dataset is collected
    assert not output.exists() and list(tmp_path.iterdir()) == []


# --- plugin metadata through LeRobot's own editing tools ---------------------------------------------


@pytest.fixture(scope="module")
def merged(tmp_path_factory) -> Path:
    """A tiny GaLR, two hands' synthetic datasets and their merge with cached latents."""
    root = tmp_path_factory.mktemp("merged")
    save_galr(root / "galr", ["umi", "inspire"])
    for seed, hand in enumerate(["umi", "inspire"]):
        write_synthetic_dataset(root / hand, hand, episodes=2, frames=8, n_points=16, seed=seed)
    inputs = [str(root / "umi"), str(root / "inspire")]
    merge = ["dataset", "merge", "--inputs", *inputs, "--output", str(root / "merged")]
    assert cli.main([*merge, "--galr", str(root / "galr")]) == 0
    return root


def _delete_episodes(root: Path, output: Path, episodes: list[int]) -> subprocess.CompletedProcess:
    command = [str(EDIT_DATASET), f"--repo_id=local/{root.name}", f"--root={root}", f"--new_root={output}",
               "--operation.type=delete_episodes", f"--operation.episode_indices={episodes}"]  # fmt: skip
    return subprocess.run(command, env=ENV, capture_output=True, text=True, timeout=300)


def test_the_record_survives_lerobot_edit_dataset(merged, tmp_path):
    """`lerobot-edit-dataset` rewrites meta/ without meta/opfa.json; the copy in meta/info.json's features
    stays, so the edited dataset still names the GaLR of its cached latents (and a clouds dataset its
    calibration)."""
    edited = tmp_path / "edited"
    result = _delete_episodes(merged / "merged", edited, [1])
    assert result.returncode == 0, result.stderr[-3000:]
    assert not (edited / OPFA_META_FILE).exists(), "LeRobot drops the plugin's file"
    record = json.loads((merged / "merged" / OPFA_META_FILE).read_text())
    assert opfa_record(edited) == record and record["galr_fingerprint"]
    meta = LeRobotDatasetMetadata("local/edited", root=edited)
    layout = read_layout(meta.features, meta.robot_type, edited)
    assert layout.galr_fingerprint == record["galr_fingerprint"] and layout.latent_dim > 0
    assert meta.total_episodes == 3


def test_a_merge_whose_record_is_gone_is_refused(merged, tmp_path):
    """A dataset merged before info.json kept the copy, then edited: its cached latents are of a GaLR
    nothing names any more; training would fall back to the default GaLR without a word."""
    old = tmp_path / "old"
    result = _delete_episodes(merged / "merged", old, [0])
    assert result.returncode == 0, result.stderr[-3000:]
    info = json.loads((old / "meta" / "info.json").read_text())
    info["features"][OBS_STATE].pop("info", None)
    (old / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    meta = LeRobotDatasetMetadata("local/old", root=old)
    with pytest.raises(ValueError, match="holds latents cached by .* but not its meta/opfa.json") as error:
        read_layout(meta.features, meta.robot_type, old)
    assert "\n" not in str(error.value) and "merge the inputs again" in str(error.value)


def test_a_dataset_without_a_record_keeps_no_stale_copy(merged, tmp_path):
    """`dataset latent` copies its input's numeric features; its own record replaces the inherited copy."""
    assert (
        cli.main(["dataset", "latent", "--input", str(merged / "merged"), "--output", str(tmp_path / "z")])
        == 0
    )
    assert opfa_record(tmp_path / "z")["latent_only"] is True
    info = json.loads((merged / "umi" / "meta" / "info.json").read_text())
    assert "info" not in info["features"][OBS_STATE], "a dataset without a record has no copy"
    assert ACTION in info["features"] and np.ndim(info["features"][OBS_STATE]["shape"]) == 1
