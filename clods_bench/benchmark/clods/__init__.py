"""The CloDS pipeline (paper section 3.3, Algorithm S1): learn cloth dynamics from multi-view video.

Stage 1 (`stage1`): fit a mesh-driven renderer on the first frames of the training videos.
Stage 2 (`extract`): recover the mesh of every later frame by optimising vertex offsets through
the renderer (L1 + gamma L_edge, eq. 6-7), cached on disk and resumable (`cache`).
Stage 3 (`stage3`): train a simulator plugin on the recovered meshes with the K-step rollout loss
(eq. 8). `pipeline.train_from_video` runs all three; the CDG task calls it when a renderer is given.
"""
