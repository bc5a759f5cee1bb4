"""Where the Cycles-vs-Mitsuba difference on the built-in scenes comes from, by ablation.

    .venv/bin/python benchmarks/breakdown_backends.py --spp 512 --width 96 --threads 1 \
        --out bench-out/breakdown/current            # ~35 min on one core

Both backends render the overview camera of `specsynth scenes preview` (as
benchmarks/compare_backends.py) under controlled variants of the backend-neutral scene (modified
copies of the RenderScene IR; the scene files are not touched), each cause of difference removed
alone and all of them together:

- ``bsdf``: every material Lambertian (specular 0, metallic 0, roughness 1, no transmission; base
  colour, textures and emission kept), which removes the Principled-model difference;
- ``world``: the world (sky model or environment map) replaced by a constant grey;
- ``sun``: the sun's 0.526 deg disc made a point (``sun_angle 0``: Cycles' sun is then a delta light
  like Mitsuba's ``directional``);
- ``emitters``: every area light replaced by a 180 deg spot light of the same hemispherical power
  (a rectangle emitter is geometry in Mitsuba, not in Cycles);
- ``all``: everything above at once: what is left should be noise.

Each variant renders with two seeds per backend, which gives per backend the self-noise PSNR
(seed 1 against seed 2: what noise alone allows at this sample count) and the PSNR between the
backends' two-seed means (2x the samples). Besides the plain PSNR, ``noise_free_db`` subtracts the
noise's expected share from the MSE (mean-of-two images carry a quarter of the seed-vs-seed MSE
each): an estimate of the PSNR that converged renders would reach (approximate: 8-bit sRGB errors
are not exactly additive). Radiance ratios are Mitsuba / Cycles mean linear radiance per channel.

The numbers before the agreement fixes were measured with this script at commit 0d03091, which
could switch them off (``--mapping legacy``, ``--fixes``). Output: a markdown table
on stdout and ``breakdown.json`` (plus the two-seed-mean PNGs) in ``--out``; a re-run into the same
folder adds or replaces variants.

Measurements behind the calibrations in backends/mitsuba/mapping.py (a few minutes each):
``--furnace`` (Principled albedo tables), ``--sky`` (sky units table), ``--shape`` (the angular
residual of the calibrated BSDF, a markdown table).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from specsynth.backend_api import load_backend
from specsynth.model.colour import linear_to_srgb8
from specsynth.model.ir import RenderScene, WorldIR, as_tuple
from specsynth.outputs.images import write_png
from specsynth.run.bench import psnr8
from specsynth.scenes import builtin_scenes, load_scene
from specsynth.spec.models import Intrinsics, QualityPreset
from specsynth.views.preview import overview_camera
from specsynth_mitsuba import mapping

CONST_WORLD = (0.2, 0.2, 0.2)  # linear radiance of the stand-in constant world


# ---------------------------------------------------------------- scene variants (IR copies)


def lambertian(rs: RenderScene) -> RenderScene:
    meshes = tuple(
        dataclasses.replace(
            m, material=dataclasses.replace(m.material, specular=0.0, metallic=0.0, roughness=1.0, transmission=0.0)
        )
        for m in rs.meshes
    )
    return dataclasses.replace(rs, meshes=meshes)


def constant_world(rs: RenderScene) -> RenderScene:
    return dataclasses.replace(rs, world=WorldIR(kind="color", color=CONST_WORLD, strength=1.0))


def point_sun(rs: RenderScene) -> RenderScene:
    return dataclasses.replace(
        rs, lights=tuple(dataclasses.replace(li, sun_angle=0.0) if li.kind == "sun" else li for li in rs.lights)
    )


def area_to_spot(rs: RenderScene) -> RenderScene:
    """Each area light becomes a 180 deg spot light 2 cm in front of it, pointing the same way,
    of twice its power (a spot's power is that of the whole-sphere point light it is cut from, so
    the half-space gets the area light's power): no emitter geometry left (Mitsuba's rectangle is a
    shape, Blender's area light is not). A bare point light there also lit the ceiling 2 cm
    behind it, which made both renders fireflies (self-noise 20-25 dB)."""
    lights = []
    for li in rs.lights:
        if li.kind == "area":
            T = li.matrix.copy()
            T[:3, 3] -= 0.02 * T[:3, 2] / np.linalg.norm(T[:3, 2])  # lights emit along local -Z
            li = dataclasses.replace(li, kind="spot", pose=as_tuple(T), power=2.0 * li.power, spot_angle=180.0, spot_blend=0.0)
        lights.append(li)
    return dataclasses.replace(rs, lights=tuple(lights))


CAUSES = {
    "bsdf": (lambertian, "all materials Lambertian"),
    "world": (constant_world, f"world = constant {CONST_WORLD[0]}"),
    "sun": (point_sun, "sun angle 0 (delta in both)"),
    "emitters": (area_to_spot, "area lights -> 180 deg spot lights"),
}


def applicable(cause: str, rs: RenderScene) -> bool:
    if cause == "sun":
        return any(li.kind == "sun" for li in rs.lights)
    if cause == "emitters":
        return any(li.kind == "area" for li in rs.lights)
    return True


def variants_for(rs: RenderScene, wanted: list[str]) -> dict[str, tuple[RenderScene, str]]:
    out = {}
    causes = [c for c in CAUSES if applicable(c, rs)]
    for v in wanted:
        if v == "as_is":
            out[v] = (rs, "as is")
        elif v == "all":
            s = rs
            for c in causes:
                s = CAUSES[c][0](s)
            out[v] = (s, "all causes removed: " + ", ".join(causes))
        elif v.startswith("only_"):  # every cause removed except one
            keep = v[5:]
            if keep not in causes:
                continue
            s = rs
            for c in causes:
                if c != keep:
                    s = CAUSES[c][0](s)
            out[v] = (s, f"only {keep} left")
        elif v.startswith("no_"):
            c = v[3:]
            if c in causes:
                out[v] = (CAUSES[c][0](rs), CAUSES[c][1])
        else:
            raise SystemExit(f"unknown variant {v!r}")
    return out


# ---------------------------------------------------------------- measuring


def mse8(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))


def db(mse: float) -> float:
    return float("inf") if mse <= 0 else round(float(10 * np.log10(255.0**2 / mse)), 2)


def compare(c: list, m: list) -> tuple[dict, np.ndarray, np.ndarray]:
    """c, m: the two seeds' RenderResults of each backend -> (numbers, the two 8-bit means)."""
    cm = linear_to_srgb8((c[0].linear + c[1].linear) / 2)
    mm = linear_to_srgb8((m[0].linear + m[1].linear) / 2)
    self_c, self_m = mse8(c[0].rgb, c[1].rgb), mse8(m[0].rgb, m[1].rgb)
    cross = mse8(cm, mm)
    noise = (self_c + self_m) / 4.0  # expected noise MSE between the two means
    lin_c = (c[0].linear + c[1].linear).reshape(-1, 3).mean(0)
    lin_m = (m[0].linear + m[1].linear).reshape(-1, 3).mean(0)
    return {
        "psnr_db": db(cross),
        "psnr_seed1_db": round(psnr8(c[0].rgb, m[0].rgb), 2),
        "noise_ceiling_db": db(noise),
        "noise_free_db": db(max(cross - noise, 1e-3)),
        "self_psnr_db": {"cycles": db(self_c), "mitsuba": db(self_m)},
        "mitsuba_over_cycles_mean_radiance": (lin_m / np.maximum(lin_c, 1e-9)).round(3).tolist(),
    }, cm, mm


# ---------------------------------------------------------------- white furnace (BSDF calibration)

FURNACE_ROUGHNESS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
FURNACE_SPECULAR = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
FURNACE_METAL = ((0.2, 0.4, 0.6, 0.8, 1.0), (0.05, 0.5, 1.0))  # roughness, base colour


def furnace(args) -> None:
    """Albedo of a dielectric Principled BSDF per roughness and specular, in both backends.

    A smooth-shaded unit sphere in a radiance-1 world, seen from 4 m: the mean over the sphere's
    disc is the BSDF's albedo averaged over cosine-weighted directions (what each bounce of a room's
    interreflection keeps). Both models are linear in the base colour, A = slope * base + intercept,
    so base 0 and 1 give both numbers. Mitsuba is measured with its raw ``principled`` (no
    calibration), Cycles with the backend's Principled BSDF.
    """
    import tempfile

    import trimesh

    from specsynth.assets.meshio import MeshData, write_mesh
    from specsynth.model.ir import CameraIR, MaterialIR, MeshInstance, as_tuple
    from specsynth.views.cameras import look_at

    tmp = Path(tempfile.mkdtemp(prefix="furnace-"))
    s = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    ply = tmp / "sphere.ply"
    write_mesh(ply, MeshData(vertices=s.vertices.astype(np.float32), faces=s.faces.astype(np.int32),
                             normals=s.vertex_normals.astype(np.float32)))
    n = 48
    f = 60.0  # sphere radius on screen: f tan(asin(1/4)) = 15.5 px
    K = np.array([[f, 0, (n - 1) / 2], [0, f, (n - 1) / 2], [0, 0, 1]])
    R, t = look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3))
    cam = CameraIR(K=as_tuple(K), width=n, height=n, R_w2c=as_tuple(R), t_w2c=as_tuple(t))
    yy, xx = np.mgrid[0:n, 0:n]
    disc = np.hypot(xx - (n - 1) / 2, yy - (n - 1) / 2) < 14.5
    q = QualityPreset(aa=args.spp, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=1)
    world = WorldIR(kind="color", color=(1.0, 1.0, 1.0), strength=1.0)
    eye = np.eye(4)

    # Mitsuba's own principled, uncalibrated: these tables are what the calibration is made from.
    opts = {"cycles": {"name": "cycles"}, "mitsuba": {"name": "mitsuba", "samples": args.spp, "match_cycles_bsdf": False}}
    table: dict = {}
    for b in ("cycles", "mitsuba"):
        backend = load_backend(b)(opts[b], threads=args.threads)
        for r in FURNACE_ROUGHNESS:
            for sp in FURNACE_SPECULAR:
                vals = []
                for base in (0.0, 1.0):
                    mat = MaterialIR(base_color=(base,) * 3, roughness=r, specular=sp, metallic=0.0)
                    if b == "mitsuba" and sp == 0.0:
                        # the mapping turns specular 0 into Lambertian; measure principled itself
                        mat = dataclasses.replace(mat, specular=1e-6)
                    inst = MeshInstance("ball", str(ply), "furnace-sphere", as_tuple(eye), mat)
                    backend.load(RenderScene(meshes=(inst,), world=world))
                    img = backend.render(cam, q, seed=7).linear
                    vals.append(float(img[disc].mean()))
                table.setdefault(b, {})[f"{r:.2f},{sp:.2f}"] = {"intercept": round(vals[0], 5), "slope": round(vals[1] - vals[0], 5)}
                print(b, r, sp, table[b][f"{r:.2f},{sp:.2f}"], flush=True)
        for r in FURNACE_METAL[0]:
            for base in FURNACE_METAL[1]:
                mat = MaterialIR(base_color=(base,) * 3, roughness=r, metallic=1.0)
                backend.load(RenderScene(meshes=(MeshInstance("ball", str(ply), "furnace-sphere", as_tuple(eye), mat),), world=world))
                a = float(backend.render(cam, q, seed=7).linear[disc].mean())
                table.setdefault(b + "_metal", {})[f"{r:.2f},{base:.2f}"] = round(a, 5)
                print(b, "metal", r, base, round(a, 5), flush=True)
        backend.close()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "furnace.json").write_text(json.dumps({"spp": args.spp, "roughness": FURNACE_ROUGHNESS,
                                                  "specular": FURNACE_SPECULAR, "albedo": table}, indent=2) + "\n")


SKY_ELEVATION = (5.0, 15.0, 30.0, 45.0, 60.0, 80.0)
SKY_TURBIDITY = (1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0)


def sky(args) -> None:
    """Sky brightness of both backends: a 1 km white Lambertian floor under the sky alone (no
    sun light), seen from 1 m: its radiance is the horizontal sky irradiance / pi. Prints the
    Cycles / Mitsuba luminance ratio per sun elevation and turbidity (mapping.SKY_UNITS)."""
    import tempfile

    from specsynth.assets.meshio import MeshData, write_mesh
    from specsynth.model.ir import CameraIR, MaterialIR, MeshInstance, as_tuple
    from specsynth.views.cameras import look_at

    tmp = Path(tempfile.mkdtemp(prefix="sky-"))
    v = np.array([[-500, -500, 0], [500, -500, 0], [500, 500, 0], [-500, 500, 0]], np.float32)
    write_mesh(tmp / "quad.ply", MeshData(vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                                          normals=np.tile(np.array([[0, 0, 1]], np.float32), (4, 1))))
    floor = MeshInstance("floor", str(tmp / "quad.ply"), "sky-floor", as_tuple(np.eye(4)),
                         MaterialIR(base_color=(1.0, 1.0, 1.0), specular=0.0, metallic=0.0, roughness=1.0))
    K = np.array([[10.0, 0, 7.5], [0, 10.0, 5.5], [0, 0, 1]])
    R, t = look_at(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.001, 0.0]), up=(0.0, 1.0, 0.0))
    cam = CameraIR(K=as_tuple(K), width=16, height=12, R_w2c=as_tuple(R), t_w2c=as_tuple(t))
    q = QualityPreset(aa=args.spp, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=1)
    lum = np.array([0.2126, 0.7152, 0.0722])
    res: dict = {}
    for b in ("cycles", "mitsuba"):
        backend = load_backend(b)({"name": b, **({"samples": args.spp} if b == "mitsuba" else {})}, threads=args.threads)
        for tu in SKY_TURBIDITY:
            for el in SKY_ELEVATION:
                w = WorldIR(kind="sky", sun_elevation=el, sun_azimuth=0.0, turbidity=tu, strength=1.0)
                backend.load(RenderScene(meshes=(floor,), world=w))
                rgb = backend.render(cam, q, seed=3).linear.reshape(-1, 3).mean(0)
                res.setdefault(f"{tu:g},{el:g}", {})[b] = rgb.round(5).tolist()
        backend.close()
    print("cycles / mitsuba luminance of the sky irradiance; rows turbidity, columns elevation", SKY_ELEVATION)
    table = {}
    for tu in SKY_TURBIDITY:
        row = []
        for el in SKY_ELEVATION:
            x = res[f"{tu:g},{el:g}"]
            # Mitsuba rendered with the current sky units: undo them to get the ratio to sunsky's own.
            units = mapping.sky_scale(1.0, tu, el)
            row.append(units * float(lum @ np.array(x["cycles"]) / (lum @ np.array(x["mitsuba"]))))
            x["ratio_rgb"] = (units * np.array(x["cycles"]) / np.array(x["mitsuba"])).round(2).tolist()
        table[tu] = row
        print(f"{tu:4g}: " + " ".join(f"{v:6.1f}" for v in row) + f"   mean {np.mean(row):.1f}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "sky.json").write_text(json.dumps({"spp": args.spp, "elevation": SKY_ELEVATION, "rgb": res,
                                              "luminance_ratio": table}, indent=2) + "\n")


def shape(args) -> None:
    """Angular shape of the (calibrated) dielectric BSDF: a 6 x 6 m floor of base 0.5, a 100 W
    point light 2 m away at elevation 90 / 45 / 20 deg, camera 2 m away at elevation 80 / 45 /
    20 deg on the light's side and opposite it; Mitsuba / Cycles radiance at the floor's centre."""
    import tempfile

    from specsynth.assets.meshio import MeshData, write_mesh
    from specsynth.model.ir import CameraIR, LightIR, MaterialIR, MeshInstance
    from specsynth.views.cameras import look_at

    tmp = Path(tempfile.mkdtemp(prefix="shape-"))
    v = np.array([[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]], np.float32)
    write_mesh(tmp / "q.ply", MeshData(vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                                       normals=np.tile(np.array([[0, 0, 1]], np.float32), (4, 1))))
    K = np.array([[30.0, 0, 7.5], [0, 30.0, 5.5], [0, 0, 1]])
    q = QualityPreset(aa=args.spp, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=1)
    cams = [(el, side) for el in (80, 45, 20) for side in (-1, 1)]
    vals: dict = {}
    for b in ("cycles", "mitsuba"):
        backend = load_backend(b)({"name": b, **({"samples": args.spp} if b == "mitsuba" else {})}, threads=args.threads)
        for r in (0.9, 0.5, 0.3):
            floor = MeshInstance("f", str(tmp / "q.ply"), "shape-floor", as_tuple(np.eye(4)),
                                 MaterialIR(base_color=(0.5,) * 3, specular=0.5, roughness=r))
            for lel in (90, 45, 20):
                T = np.eye(4)
                T[:3, 3] = 2.0 * np.array([0.0, -np.cos(np.radians(lel)), np.sin(np.radians(lel))])
                backend.load(RenderScene(meshes=(floor,), lights=(LightIR(kind="point", pose=as_tuple(T), power=100.0),),
                                         world=WorldIR(color=(0.0, 0.0, 0.0))))
                for cel, side in cams:
                    e = 2.0 * np.array([0.0, side * np.cos(np.radians(cel)), np.sin(np.radians(cel))])
                    R, t = look_at(e, np.zeros(3))
                    cam = CameraIR(K=as_tuple(K), width=16, height=12, R_w2c=as_tuple(R), t_w2c=as_tuple(t))
                    vals[(b, r, lel, cel, side)] = float(backend.render(cam, q, seed=1).linear[4:8, 6:10].mean())
        backend.close()
    print("| roughness | light elevation | " + " | ".join(f"camera {el} deg {'light side' if sd < 0 else 'opposite'}" for el, sd in cams) + " |")
    print("|---|---|" + "---|" * len(cams))
    for r in (0.9, 0.5, 0.3):
        for lel in (90, 45, 20):
            cells = [f"{vals[('mitsuba', r, lel, el, sd)] / vals[('cycles', r, lel, el, sd)]:.3f}" for el, sd in cams]
            print(f"| {r} | {lel} | " + " | ".join(cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=512)
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--mitsuba-spp", type=int, default=None, help="Mitsuba's spp if not --spp (it is noisier per sample)")
    ap.add_argument("--mitsuba-sampler", default="independent", choices=["independent", "ldsampler", "stratified", "multijitter", "orthogonal"])
    ap.add_argument("--depth", type=int, default=4)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default="bench-out/breakdown")
    ap.add_argument("--scenes", nargs="*", default=None)
    ap.add_argument(
        "--variants",
        nargs="*",
        default=["as_is", "no_bsdf", "no_world", "no_sun", "no_emitters", "all"],
        help="as_is, no_<cause>, only_<cause>, all; causes: " + ", ".join(CAUSES),
    )
    ap.add_argument("--furnace", action="store_true", help="measure the Principled albedo tables instead")
    ap.add_argument("--sky", action="store_true", help="measure the sky-brightness ratio instead")
    ap.add_argument("--shape", action="store_true", help="measure the calibrated BSDF's angular shape instead")
    args = ap.parse_args()
    if args.shape:
        return shape(args)
    if args.furnace:
        return furnace(args)
    if args.sky:
        return sky(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    w = args.width
    h = w * 3 // 4
    intr = Intrinsics(width=w, height=h, fx=0.45 * w, fy=0.45 * w, cx=w / 2 - 0.5, cy=h / 2 - 0.5)
    d = args.depth
    q = QualityPreset(aa=args.spp, diffuse_rays=args.spp, specular_rays=args.spp, diffuse_depth=d, specular_depth=d, max_depth=d)
    opts = {
        "cycles": {"name": "cycles"},
        "mitsuba": {"name": "mitsuba", "sampler": args.mitsuba_sampler, "samples": args.mitsuba_spp or args.spp},
    }
    backends = {name: load_backend(name)(opts[name], threads=args.threads) for name in ("cycles", "mitsuba")}
    results: dict = {}
    if (out / "breakdown.json").is_file():  # a re-run adds to (or replaces) variants already there
        results = json.loads((out / "breakdown.json").read_text())["scenes"]
    t_start = time.perf_counter()
    for name in args.scenes or builtin_scenes():
        scene = load_scene(name, Path.cwd())
        cam = overview_camera(scene, intr)
        base = scene.with_objects(())
        for v, (rs, label) in variants_for(base, args.variants).items():
            imgs: dict = {}
            secs, spp_used = {}, {}
            for b, backend in backends.items():
                backend.load(rs)
                t0 = time.perf_counter()
                imgs[b] = [backend.render(cam, q, seed=s) for s in (1, 2)]
                r_spp = imgs[b][0].stats.get("spp", imgs[b][0].stats.get("samples"))
                secs[b] = round((time.perf_counter() - t0) / 2, 1)
                spp_used[b] = r_spp
            r, cm, mm = compare(imgs["cycles"], imgs["mitsuba"])
            r.update(label=label, seconds_per_render=secs, spp=spp_used)
            results.setdefault(name, {})[v] = r
            write_png(out / f"{name}_{v}_cycles.png", cm)
            write_png(out / f"{name}_{v}_mitsuba.png", mm)
            print(f"{name:6s} {v:12s} {json.dumps(r)}", flush=True)
            (out / "breakdown.json").write_text(json.dumps(meta(args, w, h, backends, results), indent=2) + "\n")
    for backend in backends.values():
        backend.close()
    print(f"\n{time.perf_counter() - t_start:.0f} s in all\n")
    order = ["as_is", "no_bsdf", "no_world", "no_sun", "no_emitters", "all"]
    print(markdown(results, order + sorted({v for r in results.values() for v in r} - set(order))))


def meta(args, w, h, backends, results) -> dict:
    return {
        "command": "benchmarks/breakdown_backends.py " + " ".join(
            f"--{k.replace('_', '-')} {' '.join(map(str, v)) if isinstance(v, list) else v}"
            for k, v in vars(args).items() if v is not None
        ),
        "size": [w, h],
        "versions": {b: be.version() for b, be in backends.items()},
        "scenes": results,
    }


def markdown(results: dict, variants: list[str]) -> str:
    cols = [v for v in variants if any(v in r for r in results.values())]
    head = "| scene | " + " | ".join(cols) + " | self-noise C / M | noise ceiling (as is) |"
    lines = [head, "|" + "---|" * (len(cols) + 3)]
    for name, r in results.items():
        cells = []
        for v in cols:
            if v not in r:
                cells.append("n/a")
                continue
            x = r[v]
            ratio = x["mitsuba_over_cycles_mean_radiance"]
            cells.append(f"{x['psnr_db']:.1f} dB (~{x['noise_free_db']:.1f}); ×{np.mean(ratio):.3f}")
        first = r[cols[0]]
        sn = first["self_psnr_db"]
        lines.append(f"| `{name}` | " + " | ".join(cells) + f" | {sn['cycles']:.1f} / {sn['mitsuba']:.1f} dB | {first['noise_ceiling_db']:.1f} dB |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
