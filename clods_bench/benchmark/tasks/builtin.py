"""Registers the built-in tasks through the `clods_bench` entry-point group, like any third-party plugin: each with
its table layout (the paper's, or one column per metric) and, for CDG, the labels of its CloDS rows."""

from __future__ import annotations

from clods_bench.benchmark.clods.config import clods_device_options
from clods_bench.benchmark.core.descriptors import TableLayout, TaskSpec
from clods_bench.benchmark.core.eval_data import extra_datasets
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.benchmark.outputs.extraction_tables import extract_caption, extract_frame
from clods_bench.benchmark.outputs.image_tables import dvc_caption, dvc_frame, dvc_multi_caption, dvc_multi_frame, nvs_caption, nvs_frame
from clods_bench.benchmark.outputs.rollout_tables import cdg_caption, cdg_frame, stability_caption, stability_frame
from clods_bench.benchmark.outputs.tables import metric_frame
from clods_bench.benchmark.tasks.cdg import cdg_row_label, run_cdg
from clods_bench.benchmark.tasks.dvc import run_dvc
from clods_bench.benchmark.tasks.dvc_multi import run_dvc_multi
from clods_bench.benchmark.tasks.extract import run_extract
from clods_bench.benchmark.tasks.initial_mesh import initial_mesh_device_options, run_initial_mesh
from clods_bench.benchmark.tasks.nvs import run_nvs
from clods_bench.benchmark.tasks.stability import run_stability


@hookimpl
def clods_bench_tasks() -> list[TaskSpec]:
    return [
        TaskSpec(
            name="cdg",
            description="Cloth dynamics grounding: simulator rollout RMSE, viewed/unviewed x interpolation/extrapolation (Table 2).",
            run=run_cdg,
            needs=("sim",),
            datasets=extra_datasets,
            table=TableLayout(frame=cdg_frame, caption=cdg_caption),
            row_label=cdg_row_label,
            device_options=clods_device_options,
        ),
        TaskSpec(
            name="nvs",
            description="Dynamic-scene novel-view synthesis: renderer fitted on frame 0, driven by true meshes; PSNR/SSIM/LPIPS on held-out views (Table 3).",
            run=run_nvs,
            needs=("renderer",),
            table=TableLayout(frame=nvs_frame, caption=nvs_caption),
        ),
        TaskSpec(
            name="stability",
            description="Stability: long rollouts (2x the stored horizon) watched for NaN, runaway strain and energy; divergence step and reason.",
            run=run_stability,
            needs=("sim",),
            table=TableLayout(frame=stability_frame, caption=stability_caption, per="preset"),
        ),
        TaskSpec(
            name="dvc",
            description="DVC forward / video prediction: a video predictor (--predictor) or a simulator rolled out and rendered (--sim --renderer); PSNR/SSIM/LPIPS/RMSE (Table 4).",
            run=run_dvc,
            table=TableLayout(frame=dvc_frame, caption=dvc_caption),
            device_options=clods_device_options,
        ),
        TaskSpec(
            name="dvc_multi",
            description="Video prediction trained on several trajectories: Extrapolation (their last frames) and Generalization (unseen trajectories' first frames); PSNR/SSIM/LPIPS/RMSE (appendix table).",
            run=run_dvc_multi,
            table=TableLayout(frame=dvc_multi_frame, caption=dvc_multi_caption),
            device_options=clods_device_options,
        ),
        TaskSpec(
            name="extract",
            description="Mesh extraction (CloDS stages 1-2): E-GT, RMSE of the meshes recovered from video against the truth (ablations).",
            run=run_extract,
            needs=("renderer",),
            table=TableLayout(frame=extract_frame, caption=extract_caption),
            device_options=clods_device_options,
        ),
        TaskSpec(
            name="initial_mesh",
            description="Initial mesh (CloDS stage 0): 2DGS + TSDF + sheet mesh from frame 0's training views; attached-point RMSE and Chamfer against the true mesh.",
            run=run_initial_mesh,
            table=TableLayout(frame=metric_frame),
            device_options=initial_mesh_device_options,
        ),
    ]
