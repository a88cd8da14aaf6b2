"""The TensorFlow half of `hcmt_same_weights.py`: runs the authors' HCMT modules on weights and inputs from a file.

Run by `hcmt_same_weights.py` under an interpreter with the authors' stack (TensorFlow 2.8, dm-sonnet 2.0.1); it
imports nothing from clods-bench. The authors' `core_model.HCMT` and `normalization.Normalizer` are imported from
the checkout given; their modules' `tf` is replaced by a view of TensorFlow whose `float32` is `float64`, so the
code's float32 casts and normaliser variables run in float64, unchanged otherwise. The two edge normalisers get the
widths of 3-D cloth (7 and 4; the code's 6 and 3 are its 2-D impact domain's). Writes the outputs, the parameter
gradients of a fixed loss and the normaliser statistics after the call.

    python hcmt_reference_run.py CHECKOUT IN.npz OUT.npz
"""

from __future__ import annotations

import sys
import types

import numpy as np
import tensorflow as tf


def float64_view() -> types.ModuleType:
    """TensorFlow with `float32` meaning float64 (for the reference modules' explicit dtypes)."""
    view = types.ModuleType("tf_float64_view")
    view.__dict__.update({k: getattr(tf, k) for k in dir(tf) if not k.startswith("__")})
    view.float32 = tf.float64
    return view


def fail(message: str) -> None:
    print(message)
    raise SystemExit(1)


class Mapper:
    """Assigns named arrays to reference variables, remembering which variable got which name."""

    def __init__(self, arrays: dict[str, np.ndarray]) -> None:
        self.arrays = arrays
        self.used: set[str] = set()
        self.pairs: list[tuple[str, tf.Variable, bool]] = []  # (name, variable, transposed)

    def set(self, var: tf.Variable, name: str, transpose: bool = False, rows: slice | None = None) -> None:
        """var[rows] <- arrays[name] (transposed for Linear weights); one clear line if it cannot be mapped."""
        if name not in self.arrays:
            fail(f"weight {name}: not in the exported clods-bench state (reference variable {var.name})")
        value = self.arrays[name].T if transpose else self.arrays[name]
        target = var.numpy() if rows is not None else None
        if rows is not None:
            target[rows] = value
            value = target
        if tuple(value.shape) != tuple(var.shape):
            fail(f"weight {name}: shape {value.shape} cannot map to reference variable {var.name} of shape {tuple(var.shape)}")
        var.assign(value)
        self.used.add(name)
        self.pairs.append((name, var, transpose))


def map_mlp(m: Mapper, mlp, prefix: str, layer_norm: bool) -> None:
    """A project `make_mlp` Sequential (Linear/ReLU..., LayerNorm) onto the reference's `MLP` module."""
    net = mlp.network._layers[0] if layer_norm else mlp.network
    for i, lin in enumerate(net._layers):
        m.set(lin.w, f"{prefix}.{2 * i}.weight", transpose=True)
        m.set(lin.b, f"{prefix}.{2 * i}.bias")
    if layer_norm:
        last = 2 * len(net._layers) - 1
        m.set(mlp.network._layers[1].scale, f"{prefix}.{last}.weight")
        m.set(mlp.network._layers[1].offset, f"{prefix}.{last}.bias")


def map_block(m: Mapper, block, prefix: str, contact: bool | None) -> None:
    """A project TransformerBlock onto `GraphTransformerEdge` (contact None) or `GraphTransformerCnt`."""
    att = block.attention
    for ref_name, ours in (("Q", "query"), ("K", "key"), ("V", "value"), ("proj_mesh", "proj"), ("G_mesh", "gate")):
        m.set(getattr(att, ref_name).w, f"{prefix}.attention.{ours}.weight", transpose=True)
    latent = block.O_V.w.shape[1]
    rows = slice(0, latent) if contact is False else None  # no obstacles: O reads the mesh half only
    m.set(block.O_V.w, f"{prefix}.out.weight", transpose=True, rows=rows)
    for ref_ln, ours in (("norm_node1", "node_norm"), ("norm_node2", "ffn_norm"), ("norm_edge1", "edge_norms.mesh")):
        m.set(getattr(block, ref_ln).scale, f"{prefix}.{ours}.weight")
        m.set(getattr(block, ref_ln).offset, f"{prefix}.{ours}.bias")
    if contact:
        m.set(block.norm_edge1_cnt.scale, f"{prefix}.edge_norms.world.weight")
        m.set(block.norm_edge1_cnt.offset, f"{prefix}.edge_norms.world.bias")
    for i, name in enumerate(("ffn1", "ffn2", "ffn3")):
        m.set(getattr(block.ffn_v, name).w, f"{prefix}.ffn.{2 * i}.weight", transpose=True)


def set_normalizer(norm, arrays: dict[str, np.ndarray], prefix: str) -> None:
    norm._acc_count.assign(arrays[f"{prefix}.acc_count"])
    norm._num_accumulations.assign(float(arrays[f"{prefix}.num_accumulations"]))
    norm._acc_sum.assign(arrays[f"{prefix}.acc_sum"])
    norm._acc_sum_squared.assign(arrays[f"{prefix}.acc_sum_squared"])


def main(checkout: str, path_in: str, path_out: str) -> None:
    sys.path.insert(0, checkout)
    import core_model  # noqa: E402  (the authors' modules, from the checkout)
    import normalization  # noqa: E402

    core_model.tf = normalization.tf = float64_view()
    data = dict(np.load(path_in))
    levels, contact = int(data["levels"]), bool(data["contact"])
    if levels != 6:
        fail(f"the reference HCMT has 6 levels (l_n); the exported model has {levels}")
    ids = [tf.constant(data[f"m_ids_{i}"]) for i in range(levels + 1)]
    gs_s = [tf.constant(data[f"m_gs_s_{i}"]) for i in range(levels + 1)]
    gs_r = [tf.constant(data[f"m_gs_r_{i}"]) for i in range(levels + 1)]
    inputs = {"world_pos": tf.constant(data["world_pos"]), "mesh_pos": tf.constant(data["mesh_pos"]), "m_ids": ids, "m_gs_s": gs_s, "m_gs_r": gs_r}
    edges = {k: tf.constant(data[k]) for k in ("m_senders", "m_receivers", "c_senders", "c_receivers")}

    model = core_model.HCMT()
    model.encoder_edge_mesh._edge_mesh_normalizer = normalization.Normalizer(size=7, name="edge_mesh_normalizer")
    model.encoder_edge_cnt._edge_mesh_normalizer = normalization.Normalizer(size=4, name="edge_cnt_normalizer")
    node_normalizer = normalization.Normalizer(size=data["raw_nodes"].shape[1], name="node_normalizer")
    raw_nodes = tf.constant(data["raw_nodes"])
    model(node_normalizer(raw_nodes, False), inputs, edges, False)  # builds the variables

    params = {k[len("param.") :]: v for k, v in data.items() if k.startswith("param.")}
    m = Mapper(params)
    map_mlp(m, model.encoder_node.node_latents, "node_encoder", True)
    map_mlp(m, model.encoder_edge_mesh.edge_latents, "edge_encoders.mesh", True)
    if contact:
        map_mlp(m, model.encoder_edge_cnt.edge_latents, "edge_encoders.world", True)
    map_mlp(m, model.decoder, "decoder", False)
    for i, block in enumerate(model.firsts):
        map_block(m, block, f"processor.first.{i}", contact)
    for i in range(levels):
        map_block(m, model.downs[i], f"processor.down.{i}.0", None)
        map_block(m, model.ups[i], f"processor.up.{levels - 1 - i}.0", None)  # the code's ups run from the coarsest level
    map_block(m, model.bottom, "processor.bottom.0", None)
    unmapped = sorted(set(params) - m.used)
    if unmapped:
        fail(f"weight {unmapped[0]}: no reference variable takes it ({len(unmapped)} unmapped)")

    stats = {"node": node_normalizer, "mesh": model.encoder_edge_mesh._edge_mesh_normalizer, "world": model.encoder_edge_cnt._edge_mesh_normalizer}
    out: dict[str, np.ndarray] = {}
    for mode in ("eval", "train"):
        for key, norm in stats.items():
            if f"norm.{key}.acc_sum" in data:
                set_normalizer(norm, data, f"norm.{key}")
        training = mode == "train"
        with tf.GradientTape() as tape:
            y = model(node_normalizer(raw_nodes, training), inputs, edges, training)
            loss = tf.reduce_mean(tf.reduce_sum((tf.constant(data["target"]) - y) ** 2, axis=-1))
        out[f"{mode}.output"] = y.numpy()
        out[f"{mode}.loss"] = np.array(loss.numpy())
        grads = tape.gradient(loss, [v for _, v, _ in m.pairs])
        for (name, var, transposed), g in zip(m.pairs, grads):
            g = np.zeros(var.shape) if g is None else g.numpy()
            if not contact and name.endswith(".out.weight") and ".first." in name:
                g = g[: g.shape[0] // 2]
            out[f"{mode}.grad.{name}"] = g.T if transposed else g
        for key, norm in stats.items():
            if f"norm.{key}.acc_sum" not in data:  # no obstacles: clods-bench has no contact normaliser
                continue
            out[f"{mode}.norm.{key}.acc_sum"] = norm._acc_sum.numpy()
            out[f"{mode}.norm.{key}.acc_count"] = np.array(norm._acc_count.numpy())
    np.savez(path_out, **out)


if __name__ == "__main__":
    if len(sys.argv) != 4:
        fail("usage: hcmt_reference_run.py CHECKOUT IN.npz OUT.npz")
    main(*sys.argv[1:])
