"""Writes clods_bench_example_scene/banner.obj: a swallowtail banner (a V cut out of its bottom edge).

Run once (`python make_banner_obj.py`); the OBJ is shipped with the package. The banner hangs in the
y-z plane (x = 0), 0.6 m wide, 1.0 m tall at its sides and 0.75 m at the middle; its top edge is at
z = 1.0. Columns of nodes run from the top down to the V-shaped bottom edge, so every quad is a
trapezoid; quads are split along alternating diagonals. UVs are the rest coordinates divided by the
banner's bounding box, i.e. laid out without distortion, so clods-bench scales them back to metres.
"""

from __future__ import annotations

from pathlib import Path

WIDTH, HEIGHT, NOTCH = 0.6, 1.0, 0.25
NX, NY = 7, 9  # nodes across, nodes down each column


def banner() -> tuple[list[tuple[float, float, float]], list[tuple[float, float]], list[tuple[int, int, int]]]:
    """Vertices (x, y, z), UVs and 0-based triangles of the banner."""
    verts, uvs, faces = [], [], []
    for j in range(NY):  # row j = 0 is the bottom edge, j = NY - 1 the top
        for i in range(NX):
            y = WIDTH * i / (NX - 1)
            bottom = NOTCH * (1.0 - abs(2.0 * i / (NX - 1) - 1.0))  # the V: deepest at the middle column
            z = bottom + (HEIGHT - bottom) * j / (NY - 1)
            verts.append((0.0, y, z))
            uvs.append((y / WIDTH, z / HEIGHT))
    for j in range(NY - 1):
        for i in range(NX - 1):
            a, b = i + NX * j, i + 1 + NX * j
            c, d = b + NX, a + NX
            faces += [(a, b, d), (b, c, d)] if (i + j) % 2 else [(a, b, c), (a, c, d)]
    return verts, uvs, faces


def main() -> None:
    verts, uvs, faces = banner()
    lines = ["# swallowtail banner for clods-bench-example-scene (made by make_banner_obj.py)"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in verts]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uvs]
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in faces]
    out = Path(__file__).parent / "clods_bench_example_scene" / "banner.obj"
    out.write_text("\n".join(lines) + "\n")
    print(f"{out}: {len(verts)} vertices, {len(faces)} triangles")


if __name__ == "__main__":
    main()
