"""The TensorFlow side of `mgn_same_weights.py`: runs DeepMind's meshgraphnets code on the study's inputs and weights.

Run by `mgn_same_weights.py` with a Python that has TensorFlow 1.15 and Sonnet 1 (Python 3.7); it imports nothing of
clods-bench. Reads IN.npz (inputs, and weights under their TensorFlow variable names), writes OUT.npz:

- `a_*` (float64): `core_model.EncodeProcessDecode` on given normalised node and edge features: its output and the
  gradients of sum(output * probe) with respect to the features and every variable;
- `b_*` (float32, the code's own dtype): `cloth_model.Model` with fresh normalisers: `loss` on K input frames in turn
  (normalisers accumulating, as training does), the gradients of the last loss, then the model's next positions
  (`_build`, normalisers read only) on the last frame;
- `c_*`: one frame through `dataset.split_and_preprocess` (its training noise, seeded);
- `d_lr`: `run_model.learner`'s learning rate at the given steps.

    python examples/studies/mgn_reference_run.py /path/to/deepmind-research IN.npz OUT.npz
"""

import sys

import numpy as np


def load_reference(path):
    sys.path.insert(0, path)
    import tensorflow.compat.v1 as tf

    from meshgraphnets import cloth_model, core_model, dataset

    return tf, core_model, cloth_model, dataset


def assign_all(tf, sess, data, dtype):
    """Set every global trainable variable from data['w:<name>'] (exits naming a variable it lacks)."""
    for v in tf.trainable_variables():
        key = "w:" + v.name
        if key not in data:
            print("%s: no weight given for this reference variable" % v.name)
            raise SystemExit(1)
        v.load(data[key].astype(dtype), sess)


def part_a(tf, core_model, data, out):
    g = tf.Graph()
    with g.as_default():
        model = core_model.EncodeProcessDecode(3, int(data["latent"]), int(data["layers"]), int(data["steps"]))
        node = tf.constant(data["a_node"])
        edge = tf.constant(data["a_edge"])
        graph = core_model.MultiGraph(node, [core_model.EdgeSet("mesh_edges", edge, tf.constant(data["a_senders"]), tf.constant(data["a_receivers"]))])
        result = model(graph)
        variables = tf.trainable_variables()
        grads = tf.gradients(tf.reduce_sum(result * tf.constant(data["a_probe"])), [node, edge] + variables)
        with tf.Session(graph=g) as sess:
            sess.run(tf.global_variables_initializer())
            assign_all(tf, sess, data, np.float64)
            values = sess.run([result] + grads)
        out["a_out"], out["a_grad_node"], out["a_grad_edge"] = values[:3]
        for v, gv in zip(variables, values[3:]):
            out["a_grad:" + v.name] = gv


def part_b(tf, core_model, cloth_model, data, out):
    g = tf.Graph()
    with g.as_default():
        learned = core_model.EncodeProcessDecode(3, int(data["latent"]), int(data["layers"]), int(data["steps"]))
        model = cloth_model.Model(learned)
        ph = {
            "world_pos": tf.placeholder(tf.float32, [None, 3]), "prev|world_pos": tf.placeholder(tf.float32, [None, 3]),
            "target|world_pos": tf.placeholder(tf.float32, [None, 3]), "node_type": tf.constant(data["b_node_type"]),
            "cells": tf.constant(data["b_cells"]), "mesh_pos": tf.constant(data["b_mesh_pos"]),
        }
        loss = model.loss(ph)
        nxt = model(ph)
        variables = tf.trainable_variables()
        grads = tf.gradients(loss, variables)
        with tf.Session(graph=g) as sess:
            sess.run(tf.global_variables_initializer())
            assign_all(tf, sess, data, np.float32)
            calls = int(data["b_calls"])
            for k in range(calls):
                feed = {ph["world_pos"]: data["b_world_%d" % k], ph["prev|world_pos"]: data["b_prev_%d" % k], ph["target|world_pos"]: data["b_target_%d" % k]}
                if k < calls - 1:
                    out["b_loss_%d" % k] = sess.run(loss, feed)
                else:  # loss and gradients from one run: the normalisers accumulate once
                    values = sess.run([loss] + grads, feed)
                    out["b_loss_%d" % k] = values[0]
                    for v, gv in zip(variables, values[1:]):
                        out["b_grad:" + v.name] = gv
            out["b_next"] = sess.run(nxt, feed)


def part_c(tf, dataset, data, out):
    g = tf.Graph()
    with g.as_default():
        tf.set_random_seed(int(data["c_seed"]))
        frame = {
            "world_pos": data["c_world"][None], "prev|world_pos": data["c_prev"][None], "target|world_pos": data["c_target"][None],
            "node_type": data["c_node_type"][None],
        }
        ds = dataset.split_and_preprocess(tf.data.Dataset.from_tensors(frame), "world_pos", float(data["c_noise"]), float(data["c_gamma"]))
        item = tf.data.make_one_shot_iterator(ds).get_next()
        with tf.Session(graph=g) as sess:
            got = sess.run(item)
        out["c_world"], out["c_target"] = got["world_pos"], got["target|world_pos"]


def part_d(tf, data, out):
    g = tf.Graph()
    with g.as_default():
        step = tf.placeholder(tf.int64, [])
        lr = tf.train.exponential_decay(learning_rate=1e-4, global_step=step, decay_steps=int(5e6), decay_rate=0.1) + 1e-6
        with tf.Session(graph=g) as sess:
            out["d_lr"] = np.array([sess.run(lr, {step: int(s)}) for s in data["d_steps"]])


def main():
    ref, path_in, path_out = sys.argv[1:4]
    tf, core_model, cloth_model, dataset = load_reference(ref)
    data = dict(np.load(path_in))
    out = {}
    part_a(tf, core_model, data, out)
    if "b_calls" in data:  # parts B-D ride along with one of the part A cases
        part_b(tf, core_model, cloth_model, data, out)
        part_c(tf, dataset, data, out)
        part_d(tf, data, out)
    np.savez(path_out, **out)


if __name__ == "__main__":
    main()
