"""Stage 2's read-ahead: every frame read once and in order, the next one read while the current one is used, and
the same extracted meshes with and without it."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest
import torch

from clods_bench.benchmark.clods.config import ClodsConfig
from clods_bench.benchmark.clods.extract import extract_trajectory
from clods_bench.benchmark.clods.prefetch import frames_ahead

from .conftest import smooth_deformation


class RecordingVideo:
    """A frame array that records which frames were read, by which thread, and signals each read."""

    def __init__(self, frames: np.ndarray) -> None:
        self.frames, self.shape = frames, frames.shape
        self.reads: list[tuple[int, str]] = []
        self.read_event = {t: threading.Event() for t in range(frames.shape[0])}

    def __getitem__(self, t: int) -> np.ndarray:
        self.reads.append((int(t), threading.current_thread().name))
        self.read_event[int(t)].set()
        return self.frames[t].copy()


@pytest.mark.parametrize("ahead", [True, False])
def test_every_frame_is_read_once_in_order_and_equals_the_array(ahead):
    frames = np.random.default_rng(0).integers(0, 256, size=(6, 2, 4, 5, 3), dtype=np.uint8)
    video = RecordingVideo(frames)
    got = list(frames_ahead(video, 2, 6, ahead=ahead))
    assert [t for t, _ in got] == [2, 3, 4, 5]
    for t, frame in got:
        np.testing.assert_array_equal(frame, frames[t])
    assert [t for t, _ in video.reads] == [2, 3, 4, 5]
    workers = {name for _, name in video.reads}
    assert (workers == {threading.current_thread().name}) != ahead  # ahead: read by the worker, not the caller


def test_the_next_frame_is_read_while_the_caller_holds_the_current_one():
    video = RecordingVideo(np.zeros((4, 1, 2, 2, 3), np.uint8))
    for t, _ in frames_ahead(video, 0, 4):
        if t + 1 < 4:  # the caller has not asked for t+1 yet, and it is read (or being read) all the same
            assert video.read_event[t + 1].wait(timeout=10.0), t
        else:
            assert len(video.reads) == 4


def test_empty_range_reads_nothing_and_a_failed_read_raises_for_its_frame():
    video = RecordingVideo(np.zeros((3, 1, 2, 2, 3), np.uint8))
    assert list(frames_ahead(video, 3, 3)) == [] and video.reads == []

    class Broken(RecordingVideo):
        def __getitem__(self, t: int) -> np.ndarray:
            if t == 2:
                raise OSError("chunk 2 failed its checksum")
            return super().__getitem__(t)

    seen = []
    with pytest.raises(OSError, match="chunk 2"):
        for t, _ in frames_ahead(Broken(np.zeros((3, 1, 2, 2, 3), np.uint8)), 0, 3):
            seen.append(t)
    assert seen == [0, 1]


def test_stage2_extracts_the_same_meshes_with_and_without_read_ahead(scene):
    r, cams, verts, nt = scene["renderer"], scene["cams"], scene["verts"], scene["node_type"]
    truth = np.stack([verts] + [smooth_deformation(verts, nt, 0.02 * k) for k in (1, 2)])
    with torch.no_grad():
        frames = np.stack([(r.render(torch.from_numpy(t), cams).numpy() * 255).round().astype(np.uint8) for t in truth])
    cfg = ClodsConfig(iterations=4, min_iterations=4, gamma=0.001)
    video = RecordingVideo(frames)
    with_ahead = extract_trajectory(r, cams, video, verts, scene["cells"], nt, cfg)
    without = extract_trajectory(r, cams, frames, verts, scene["cells"], nt, dataclasses.replace(cfg, read_ahead=False))
    np.testing.assert_array_equal(with_ahead.world_pos, without.world_pos)
    np.testing.assert_array_equal(with_ahead.loss, without.loss)
    assert [t for t, _ in video.reads] == [1, 2]
    assert ClodsConfig().extraction_identity() == dataclasses.replace(ClodsConfig(), read_ahead=False).extraction_identity()
