"""Renderer plugins (GaMeS, SMGS, per-frame 3DGS) built on the splatting core in `clods_bench.splatting`."""
