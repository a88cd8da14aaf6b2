"""`data import-video`: a dataset from your own multi-view captures (per-camera image folders or videos + transforms.json).

One capture (one `transforms.json`) becomes one trajectory; several captures of the same fixed camera rig (same
cameras, same frame count) make a dataset with train and test trajectories (each capture's top-level `split`,
default train). `transforms.json` follows NeRF / nerfstudio (camera-to-world, OpenGL axes; see `datasets.nerf`):
every entry of `frames` has a `file_path` (an image, a folder of images or a video of one camera) and a
`transform_matrix`; intrinsics `fl_x, fl_y, cx, cy, w, h` per entry or shared at the top level; the camera of an
entry is its `camera` key, else the video's file stem, the folder's name or the image's parent folder. Frame rate:
top-level `dt` or `fps`, else the videos' own rate, else `--fps`; they must agree. Masks (an alpha channel, or a
folder per camera of one mask image per frame) turn masked pixels into the background colour, white, as the
benchmark's renderer draws it. Meshes (`--meshes DIR`: one OBJ/PLY per frame, plus `topology.npz` as written
by `data export --format nerf`) are optional; a dataset without them runs the tasks that need no ground truth mesh.

All or nothing: every input is checked while the frames are streamed into a temporary folder next to `--out`, which
is renamed into place only when the whole dataset is written; on any error it is removed and `--out` is untouched.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.nerf import TOPOLOGY, camera_from_c2w_gl, check_c2w, read_transforms
from clods_bench.datasets.splits import SPLITS
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import NORMAL, Trajectory
from clods_bench.errors import ClodsError

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
MESH_SUFFIXES = (".obj", ".ply")
BACKGROUND = 255
"""The background colour (white, every channel) of the benchmark's frames: what masked pixels become."""
FOREGROUND_THRESHOLD = 16
"""A pixel is foreground when some channel differs from the background by more than this (codec noise stays below)."""
INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
SCENE = "imported"
VIDEO_HINT = 'reading videos needs PyAV: pip install "clods-bench[video]" (the `video` extra, av>=12)'


def _av() -> Any:
    """The PyAV module, or None when the optional `video` extra is not installed."""
    try:
        import av
    except ImportError:
        return None
    return av


@dataclass
class CameraSource:
    """One camera of a capture: where its frames (and masks) come from, and its parameters as given."""

    name: str
    where: str  # 'transforms.json: frames[i]' of its first entry
    c2w: np.ndarray
    intrinsics: dict[str, Any]
    images: list[Path] = field(default_factory=list)
    video: Path | None = None
    masks: list[Path] | None = None
    camera: Camera | None = None


@dataclass
class Capture:
    """One parsed transforms.json: its cameras (in order of first appearance), frame count, dt, split, meshes folder."""

    path: Path
    cameras: list[CameraSource]
    num_frames: int
    dt: float
    split: str
    meshes: Path | None
    doc: dict[str, Any]


def _number(doc: dict[str, Any], key: str, where: str) -> float | None:
    value = doc.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
        raise ClodsError(f"must be a positive number, got {value!r}", where=f"{where}.{key}")
    return float(value)


def _video_info(path: Path) -> tuple[int, float, int, int]:
    """(frame count, frames per second, width, height) of a video file."""
    av = _av()
    if av is None:
        raise ClodsError("cannot read a video without PyAV", where=str(path), hint=VIDEO_HINT)
    if not path.is_file():
        raise ClodsError("video file not found", where=str(path))
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise ClodsError("file holds no video stream", where=str(path))
            stream = container.streams.video[0]
            rate = stream.average_rate or stream.guessed_rate
            count = int(stream.frames) or sum(1 for p in container.demux(stream) if p.size)
            return count, float(rate) if rate else float("nan"), int(stream.codec_context.width), int(stream.codec_context.height)
    except ClodsError:
        raise
    except Exception as exc:  # PyAV raises its own error types for damaged files
        raise ClodsError(f"cannot read video: {type(exc).__name__}: {exc}", where=str(path)) from None


def _video_frames(path: Path) -> Iterator[np.ndarray]:
    """The frames of a video as (H, W, 3) uint8 RGB, decoded one at a time."""
    av = _av()
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        for frame in container.decode(stream):
            yield frame.to_ndarray(format="rgb24")


def _images_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))


def _read_image(path: Path) -> np.ndarray:
    """(H, W, 3 or 4) uint8; ClodsError naming the file when it cannot be read or is not 8-bit."""
    import imageio.v3 as iio

    try:
        img = np.asarray(iio.imread(path))
    except Exception as exc:  # imageio raises many types for unreadable files
        raise ClodsError(f"cannot read image: {type(exc).__name__}: {exc}", where=str(path)) from None
    if img.dtype != np.uint8:
        raise ClodsError(f"expected 8-bit images, got {img.dtype}", where=str(path))
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ClodsError(f"expected an RGB or RGBA image, got shape {img.shape}", where=str(path))
    return img


def _composite(rgb: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Masked pixels become the background: rgb * a + 255 * (1 - a), a = alpha / 255 (a binary mask replaces)."""
    if alpha.min() == 255:
        return np.ascontiguousarray(rgb)
    a = alpha[..., None].astype(np.float32) / 255.0
    return np.rint(rgb.astype(np.float32) * a + BACKGROUND * (1.0 - a)).astype(np.uint8)


def parse_capture(path: Path, masks: str | None = None, meshes: str | None = None, fps: float | None = None) -> Capture:
    """Read and check a capture's transforms.json, its image/video files, masks and meshes (no pixels decoded yet)."""
    path = Path(path)
    doc = read_transforms(path)
    base = path.parent
    frames = doc.get("frames")
    if not isinstance(frames, list) or not frames:
        raise ClodsError("needs a non-empty list 'frames'", where=f"{path}: frames")
    shared = {k: doc[k] for k in INTRINSICS if k in doc}
    cams: dict[str, CameraSource] = {}
    keys: dict[str, list[tuple[Any, Path]]] = {}
    for i, entry in enumerate(frames):
        where = f"{path}: frames[{i}]"
        if not isinstance(entry, dict):
            raise ClodsError("must be an object", where=where)
        rel = entry.get("file_path")
        if not isinstance(rel, str) or not rel:
            raise ClodsError("missing (the image, image folder or video of this entry)", where=f"{where}.file_path")
        if "transform_matrix" not in entry:
            raise ClodsError("missing (the camera-to-world matrix)", where=f"{where}.transform_matrix")
        c2w = check_c2w(entry["transform_matrix"], f"{where}.transform_matrix")
        intr = {**shared, **{k: entry[k] for k in INTRINSICS if k in entry}}
        for key in INTRINSICS:
            if key in intr:
                _number(intr, key, where)
        if "fl_x" not in intr:
            raise ClodsError("missing (focal length in pixels; per entry or at the top level)", where=f"{where}.fl_x")
        source = base / rel
        is_video = source.suffix.lower() in VIDEO_SUFFIXES
        name = entry.get("camera") or (source.stem if is_video else source.name if source.is_dir() else source.parent.name)
        name = str(name)
        cam = cams.get(name)
        if cam is None:
            cam = cams[name] = CameraSource(name, where, c2w, intr)
            keys[name] = []
        elif not np.allclose(cam.c2w, c2w, atol=1e-9) or cam.intrinsics != intr:
            raise ClodsError(f"camera '{name}' differs from its first entry ({cam.where}): moving cameras are not supported",
                             where=f"{where}.transform_matrix", hint="give each camera one fixed matrix and intrinsics")  # fmt: skip
        if is_video:
            if cam.video is not None or keys[name]:
                raise ClodsError(f"camera '{name}' is given more than one source", where=f"{where}.file_path")
            if not source.is_file():
                raise ClodsError("video file not found", where=f"{where}.file_path ({source})")
            cam.video = source
        elif source.is_dir():
            if cam.video is not None or keys[name]:
                raise ClodsError(f"camera '{name}' is given more than one source", where=f"{where}.file_path")
            found = _images_in(source)
            if not found:
                raise ClodsError("folder holds no PNG/JPEG images", where=f"{where}.file_path ({source})")
            keys[name].extend((k, p) for k, p in enumerate(found))
        else:
            if cam.video is not None:
                raise ClodsError(f"camera '{name}' is given more than one source", where=f"{where}.file_path")
            if not source.is_file():
                raise ClodsError("image file not found", where=f"{where}.file_path ({source})")
            keys[name].append((entry.get("frame", rel), source))
    for name, cam in cams.items():
        if cam.video is None:
            try:
                cam.images = [p for _, p in sorted(keys[name], key=lambda kp: kp[0])]
            except TypeError:
                raise ClodsError(f"camera '{name}': 'frame' keys must all be numbers", where=f"{path}: frames") from None

    # frame counts and rates
    counts: dict[str, int] = {}
    rates: dict[str, float] = {}
    sizes: dict[str, tuple[int, int]] = {}
    for name, cam in cams.items():
        if cam.video is not None:
            counts[name], rate, w, h = _video_info(cam.video)
            rates[name] = rate
            sizes[name] = (w, h)
        else:
            counts[name] = len(cam.images)
    first = next(iter(cams))
    for name, n in counts.items():
        if n != counts[first]:
            src = cams[name].video or cams[name].images[0].parent
            raise ClodsError(f"camera '{name}' has {n} frames, camera '{first}' has {counts[first]}", where=str(src),
                             hint="every camera needs the same number of frames (trim the videos to a common span)")  # fmt: skip
    num_frames = counts[first]
    if num_frames < 2:
        raise ClodsError(f"{num_frames} frame(s) per camera, need at least 2", where=f"{path}: frames")
    video_rates = {n: r for n, r in rates.items() if np.isfinite(r)}
    if video_rates:
        ref = next(iter(video_rates))
        for name, r in video_rates.items():
            if not np.isclose(r, video_rates[ref], rtol=1e-6):
                raise ClodsError(f"video frame rate {r:g} fps, camera '{ref}' has {video_rates[ref]:g} fps", where=str(cams[name].video),
                                 hint="all cameras must be recorded (or resampled) at one frame rate")  # fmt: skip
    given = {"dt": _number(doc, "dt", str(path)), "fps": _number(doc, "fps", str(path)), "--fps": fps}
    dts = {k: (v if k == "dt" else 1.0 / v) for k, v in given.items() if v is not None}
    if video_rates:
        dts["video frame rate"] = 1.0 / next(iter(video_rates.values()))
    if not dts:
        raise ClodsError("frame rate unknown", where=f"{path}: fps", hint="give 'fps' or 'dt' in transforms.json, or --fps")
    dt = next(iter(dts.values()))
    for source, value in dts.items():
        if not np.isclose(value, dt, rtol=1e-6):
            raise ClodsError(f"frame interval {value:.6g} s from {source} disagrees with {dt:.6g} s from {next(iter(dts))}",
                             where=f"{path}: fps")  # fmt: skip

    # image sizes from the intrinsics (else the first frame), then the cameras
    for name, cam in cams.items():
        if "w" not in cam.intrinsics or "h" not in cam.intrinsics:
            w, h = sizes[name] if name in sizes else _read_image(cam.images[0]).shape[1::-1]
            cam.intrinsics = {"w": w, "h": h, **cam.intrinsics}
        intr = cam.intrinsics
        full = {"fl_x": intr["fl_x"], "fl_y": intr.get("fl_y", intr["fl_x"]), "cx": intr.get("cx", intr["w"] / 2.0),
                "cy": intr.get("cy", intr["h"] / 2.0), "w": intr["w"], "h": intr["h"]}  # fmt: skip
        if int(full["w"]) != full["w"] or int(full["h"]) != full["h"]:
            raise ClodsError(f"image size must be whole pixels, got w={full['w']}, h={full['h']}", where=f"{cam.where}.w")
        cam.camera = camera_from_c2w_gl(cam.c2w, full, f"{cam.where}.transform_matrix")
        if name in sizes and sizes[name] != (cam.camera.width, cam.camera.height):
            raise ClodsError(f"video is {sizes[name][0]}x{sizes[name][1]} but transforms.json says w={cam.camera.width}, "
                             f"h={cam.camera.height}", where=f"{cam.video} ({cam.where}.w/h)")  # fmt: skip
    c0 = cams[first].camera
    for name, cam in cams.items():
        if (cam.camera.width, cam.camera.height) != (c0.width, c0.height):
            raise ClodsError(f"camera '{name}' is {cam.camera.width}x{cam.camera.height}, camera '{first}' {c0.width}x{c0.height}",
                             where=f"{cam.where}.w", hint="the store keeps one image size for all cameras: resize first")  # fmt: skip

    if masks:
        for name, cam in cams.items():
            folder = base / masks / name
            if not folder.is_dir():
                raise ClodsError(f"mask folder of camera '{name}' not found", where=str(folder))
            cam.masks = _images_in(folder)
            if len(cam.masks) != num_frames:
                raise ClodsError(f"{len(cam.masks)} mask images, camera '{name}' has {num_frames} frames", where=str(folder))
    split = doc.get("split", "train")
    if split not in SPLITS:
        raise ClodsError(f"unknown split {split!r}, expected one of {SPLITS}", where=f"{path}: split")
    mesh_dir = None
    if meshes:
        mesh_dir = base / meshes
        if not mesh_dir.is_dir():
            raise ClodsError("mesh folder not found", where=str(mesh_dir))
    return Capture(path, list(cams.values()), num_frames, dt, split, mesh_dir, doc)


def capture_steps(cap: Capture) -> Iterator[np.ndarray]:
    """The capture's (N, H, W, 3) uint8 frames, one time step at a time, masked, with every size checked."""
    cams = cap.cameras
    videos = {c.name: _video_frames(c.video) for c in cams if c.video is not None}
    for t in range(cap.num_frames):
        step = np.empty((len(cams), cams[0].camera.height, cams[0].camera.width, 3), np.uint8)
        for n, cam in enumerate(cams):
            if cam.video is not None:
                src = f"{cam.video} frame {t}"
                try:
                    img = next(videos[cam.name])
                except StopIteration:
                    raise ClodsError(f"video ended after {t} frames, expected {cap.num_frames}", where=str(cam.video)) from None
            else:
                src = str(cam.images[t])
                img = _read_image(cam.images[t])
            h, w = img.shape[:2]
            if (w, h) != (cam.camera.width, cam.camera.height):
                raise ClodsError(f"image is {w}x{h} but transforms.json says w={cam.camera.width}, h={cam.camera.height}",
                                 where=f"{src} ({cam.where}.w/h)")  # fmt: skip
            alpha = img[..., 3] if img.shape[2] == 4 else np.full((h, w), 255, np.uint8)
            if cam.masks is not None:
                mask = _read_image(cam.masks[t])
                if mask.shape[:2] != (h, w):
                    raise ClodsError(f"mask is {mask.shape[1]}x{mask.shape[0]}, its frame {w}x{h}", where=f"{cam.masks[t]} (size)")
                m = mask[..., 3] if mask.shape[2] == 4 and mask[..., 3].min() < 255 else mask[..., 0]
                alpha = np.minimum(alpha, m)
            step[n] = _composite(img[..., :3], alpha)
            if t == 0 and not (np.abs(step[n].astype(np.int16) - BACKGROUND) > FOREGROUND_THRESHOLD).any():
                raise ClodsError("first frame shows no foreground: every pixel is the background colour (white) after masking",
                                 where=f"{src} ({cam.where})", hint="the cloth must be visible in every camera's first frame")  # fmt: skip
        yield step


def load_mesh_sequence(folder: Path, num_frames: int, dt: float) -> Trajectory:
    """A Trajectory from one OBJ/PLY per frame (sorted by name) and, when present, topology.npz (cells, mesh_pos, node_type)."""
    import trimesh

    from clods_bench.datasets.mesh_io import mesh_from_file

    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in MESH_SUFFIXES)
    if len(files) != num_frames:
        raise ClodsError(f"{len(files)} mesh files, the videos have {num_frames} frames", where=str(folder))
    verts = []
    for p in files:
        try:
            tm = trimesh.load(str(p), force="mesh", process=False, maintain_order=True)
        except Exception as exc:  # trimesh raises many types for malformed files
            raise ClodsError(f"cannot read mesh: {type(exc).__name__}: {exc}", where=str(p)) from None
        if verts and np.asarray(tm.vertices).shape != verts[0].shape:
            raise ClodsError(f"{len(tm.vertices)} vertices, {files[0].name} has {len(verts[0])}", where=str(p))
        if not verts:
            faces = np.asarray(tm.faces, np.int32)
        verts.append(np.asarray(tm.vertices, np.float64))
    topo = folder / TOPOLOGY
    if topo.is_file():
        with np.load(topo, allow_pickle=False) as npz:
            cells, mesh_pos, node_type = npz["cells"], npz["mesh_pos"], npz["node_type"]
        if cells.shape != faces.shape or not np.array_equal(np.sort(cells, 1), np.sort(faces, 1)):
            raise ClodsError(f"cells differ from the faces of {files[0].name}", where=str(topo))
    else:
        mesh = mesh_from_file(files[0])
        cells, mesh_pos, node_type = mesh.cells, mesh.mesh_pos, np.full(len(verts[0]), NORMAL, np.int32)
    traj = Trajectory(cells.astype(np.int32), mesh_pos.astype(np.float32), node_type.astype(np.int32),
                      np.stack(verts).astype(np.float32), float(dt), {"meshes": str(folder)})  # fmt: skip
    traj.validate(str(folder))
    return traj


def import_video(
    transforms: Sequence[Path], out: Path, masks: str | None = None, meshes: str | None = None,
    num_views_test: int | None = None, interp_steps: int | None = None, fps: float | None = None, force: bool = False,
) -> DatasetStore:  # fmt: skip
    """Import captures (one transforms.json each, one trajectory each) into a new dataset at `out`; all or nothing."""
    if not transforms:
        raise ClodsError("no capture given", where="import-video", hint="pass one or more transforms.json files")
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not force:
        raise ClodsError("output folder exists and is not empty", where=str(out), hint="choose a new folder, or --force to replace it")
    caps = [parse_capture(Path(p), masks, meshes, fps) for p in transforms]
    first = caps[0]
    for cap in caps[1:]:
        names = [c.name for c in cap.cameras]
        if names != [c.name for c in first.cameras] or not all(_same_camera(a.camera, b.camera) for a, b in zip(cap.cameras, first.cameras)):
            raise ClodsError(f"cameras differ from those of {first.path}", where=f"{cap.path}: frames",
                             hint="one dataset is one fixed camera rig; import other rigs as separate datasets")  # fmt: skip
        if cap.num_frames != first.num_frames or not np.isclose(cap.dt, first.dt, rtol=1e-6):
            raise ClodsError(f"{cap.num_frames} frames at dt={cap.dt:g}, {first.path} has {first.num_frames} at dt={first.dt:g}",
                             where=f"{cap.path}: frames")  # fmt: skip
    num_cams, num_frames = len(first.cameras), first.num_frames
    nvt = int(num_views_test if num_views_test is not None else first.doc.get("num_views_test", max(1, num_cams // 6)))
    interp = int(interp_steps if interp_steps is not None else first.doc.get("interp_steps", round(0.75 * (num_frames - 1))))
    if not 0 <= nvt < num_cams:
        raise ClodsError(f"must be in [0, {num_cams}) for {num_cams} cameras, got {nvt}", where="--num-views-test")
    if not 2 <= interp < num_frames - 1:
        raise ClodsError(f"must satisfy 2 <= interp_steps < {num_frames - 1} for {num_frames} frames, got {interp}", where="--interp-steps")
    order = [c for c in caps if c.split == "train"] + [c for c in caps if c.split == "test"]
    cam0 = first.cameras[0].camera
    config = {"source": "import-video", "num_train": sum(c.split == "train" for c in caps), "num_test": sum(c.split == "test" for c in caps),
              "num_steps": num_frames, "interp_steps": interp, "num_cameras": num_cams, "num_views_test": nvt,
              "image_size": cam0.width, "width": cam0.width, "height": cam0.height, "dt": first.dt, "meshes": bool(meshes),
              "camera_names": [c.name for c in first.cameras], "captures": [str(c.path.resolve()) for c in order]}  # fmt: skip
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".importing", dir=out.parent))
    try:
        store = DatasetStore.create(tmp, SCENE, config, [c.camera for c in first.cameras], meshes=bool(meshes))
        for index, cap in enumerate(order):
            meta = {"source": str(cap.path.resolve())}
            if cap.meshes is not None:
                traj = load_mesh_sequence(cap.meshes, num_frames, cap.dt)
                traj.meta.update(meta)
                store.write_trajectory(index, cap.split, index, traj, capture_steps(cap))
            else:
                store.write_video_trajectory(index, cap.split, index, capture_steps(cap), num_frames, cap.dt, meta)
        (tmp / ".manifest.lock").unlink(missing_ok=True)
        if out.exists():
            old = out.with_name(f".{out.name}.replaced")
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old)
        else:
            os.replace(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return DatasetStore.open(out)


def _same_camera(a: Camera, b: Camera) -> bool:
    return (a.width, a.height) == (b.width, b.height) and all(np.allclose(getattr(a, k), getattr(b, k), atol=1e-9) for k in ("K", "R", "t"))


__all__ = ["import_video", "parse_capture", "capture_steps", "load_mesh_sequence", "BACKGROUND"]
