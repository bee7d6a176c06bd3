"""``tlessbot parts build``: a CAD folder -> a parts folder (:mod:`tlessbot_ros.io.parts`).

The classifier and the templates are made by ``tlessbot train`` and ``tlessbot templates``, run
as they are run by hand (so a change of their defaults reaches every parts folder); the
self-check by ``tlessbot simulate`` and ``tlessbot evaluate``. ``tlessbot evaluate`` without
--classifier / --templates builds through :func:`build_parts` too (cached by the CAD content).

Where the time goes (docs/bench/own-parts.md): the classifier's simulated scenes and its
training take most of it. The templates are made in a second process while the classifier
trains (they need each other's nothing), the classifier's scenes are rendered over the CPUs
(``train --workers``), and a classifier is trained once per CAD content, recipe, seed and
training options: it does not depend on the rig, so a build for another cell, or
``tlessbot evaluate --models`` after ``parts build``, reuses it from the start-up cache.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from tlessbot_ros.errors import ModelFileError, TlessbotError
from tlessbot_ros.io import parts as parts_io

DEFAULT_RECIPE = 'hybrid'
CHECK_FRAMES = 12
# part of a cached classifier's key: raise it when a change of the code makes other models
CLASSIFIER_CACHE_VERSION = 1
HARD_RECALL = 0.8        # a part below this 5 cm / 5 deg recall in the self-check is "hard"


@dataclass
class BuildOptions:
    """How a parts folder is built (the defaults are ``tlessbot parts build``'s)."""

    units: str = 'mm'
    recipe: str | None = DEFAULT_RECIPE
    config: Path | None = None
    check_frames: int = CHECK_FRAMES
    check_depth: str = 'per_pixel'   # the self-check's simulated depth (simulate --depth-model)
    seed: int = 0
    train_args: list[str] = field(default_factory=list)
    reuse_classifier: bool = True
    # share of the classifier's training views and scenes with stereo-like depth
    # (train --smoothed-share, 0-1; 0: per-pixel depth only)
    smoothed_share: float = 0.0


# the build step that readies the pose stage's start-up caches of the new templates
STARTUP_CACHES = 'start-up caches'


def run_tool(command: str, *args: str) -> None:
    """``tlessbot <command> ARGS`` in a child process (its own progress bars).

    Raises:
        TlessbotError: it failed.
    """
    result = subprocess.run([sys.executable, '-m', 'tlessbot_ros.tools.cli', command, *args])
    if result.returncode != 0:
        raise TlessbotError(f'tlessbot {command} failed (exit {result.returncode}); its '
                            'message is above')


def start_tool(command: str, *args: str, log: Path) -> subprocess.Popen:
    """``tlessbot <command> ARGS`` started in a child process, its output to ``log``."""
    with open(log, 'wb') as out:
        return subprocess.Popen([sys.executable, '-m', 'tlessbot_ros.tools.cli', command,
                                 *args], stdout=out, stderr=subprocess.STDOUT)


def finish_tool(command: str, process: subprocess.Popen, log: Path) -> None:
    """Wait for a :func:`start_tool` child; its log's end in the error when it failed.

    Raises:
        TlessbotError: it failed.
    """
    if process.wait() != 0:
        tail = log.read_text(errors='replace').strip().splitlines()[-5:]
        raise TlessbotError(f'tlessbot {command} failed (exit {process.returncode}): '
                            + ' | '.join(line.strip() for line in tail))


def classifier_cache_path(fingerprint: str, options: BuildOptions) -> Path:
    """Where the classifier of a CAD content (``fingerprint``) and the training settings of
    ``options`` is kept (the rig is not in it: the classifier does not depend on it)."""

    from tlessbot_ros.io.cache import cache_dir

    settings = [CLASSIFIER_CACHE_VERSION, fingerprint, options.recipe, options.seed,
                options.train_args]
    if options.smoothed_share:   # without it, the key of the classifiers trained before it
        settings.append(options.smoothed_share)
    key = json.dumps(settings)
    return cache_dir() / 'classifiers' / f'{hashlib.sha256(key.encode()).hexdigest()[:24]}.npz'


def _train_classifier(out: Path, options: BuildOptions, fingerprint: str) -> None:
    """The parts folder's classifier: trained (``tlessbot train``), or the one trained before
    from the same CAD content and settings; a new one is kept for later builds."""
    cached = classifier_cache_path(fingerprint, options)
    target = out / parts_io.CLASSIFIER
    if options.reuse_classifier and cached.is_file():
        print(f'classifier: the one trained before from the same CAD files and settings '
              f'({cached})')
        shutil.copyfile(cached, target)
        return
    recipe = ['--recipe', options.recipe] if options.recipe else []
    run_tool('train', '--models', str(out / parts_io.MODELS), '--out', str(target), '--seed',
             str(options.seed), *recipe, '--smoothed-share', f'{options.smoothed_share:g}',
             *options.train_args)
    try:   # atomic: a build beside this one never reads half a file
        cached.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=cached.parent, suffix='.npz',
                                         delete=False) as tmp:
            pass
        shutil.copyfile(target, tmp.name)
        Path(tmp.name).replace(cached)
    except OSError as error:   # a read-only cache costs the next build its time only
        print(f'warning: classifier not cached ({error})')


def read_meshes(parts: list[parts_io.CadPart], units: str) -> dict[str, tuple]:
    """Every part's checked mesh ((V, 3) m, (F, 3)) by name, its warnings printed: a folder
    with an unusable mesh is refused before any work starts."""
    meshes, problems = {}, []
    for part in parts:
        try:
            vertices, faces, warnings = parts_io.read_part_mesh(part.path, units=units)
        except ModelFileError as error:   # every unusable file at once, not one per try
            problems.append(str(error))
            continue
        for warning in warnings:
            print(f'warning: {warning}')
        meshes[part.name] = (vertices, faces)
    if problems:
        raise ModelFileError(parts_io.problems_listed(problems, len(parts)))
    return meshes


def _write_models(cad: Path, out: Path, meshes: dict[str, tuple]) -> list[dict]:
    """The CAD files as ``out/models/obj_NN.ply`` (mm) + models_info.json; manifest entries."""
    from tlessbot_ros.core.common import (
        detect_symmetries,
        symmetries_from_models_info,
        symmetries_to_models_info,
    )
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.tools.support.models_info import model_geometry_mm

    models_dir = out / parts_io.MODELS
    models_dir.mkdir(parents=True, exist_ok=True)
    parts = parts_io.cad_parts(cad)
    for part in parts:
        vertices, faces = meshes[part.name]
        parts_io.write_mesh(models_dir / f'obj_{part.obj_id:02d}.ply', vertices * 1000.0, faces)
    listed = _listed_symmetries(cad, parts)
    models = load_models(models_dir)
    info, entries = {}, []
    for part in parts:
        model = models[part.obj_id]
        if part.name in listed:
            entry = {k: v for k, v in listed[part.name].items() if k.startswith('sym')}
        else:
            entry = symmetries_to_models_info(detect_symmetries(
                model.vertices, model.faces, diameter=model.diameter_m))
        geometry = {k: round(float(v), 4) for k, v in model_geometry_mm(model).items()}
        info[str(part.obj_id)] = {**geometry, **entry}
        entries.append({'id': part.obj_id, 'name': part.name, 'source': part.path.name,
                        'size_mm': [geometry[f'size_{a}'] for a in 'xyz'],
                        'diameter_mm': geometry['diameter'],
                        'symmetry': symmetries_from_models_info(info[str(part.obj_id)])
                        .describe()})
    (models_dir / 'models_info.json').write_text(json.dumps(info, indent=1) + '\n')
    return entries


def _listed_symmetries(cad: Path, parts: list[parts_io.CadPart]) -> dict[str, dict]:
    """Symmetries the CAD folder lists, by part name: ``symmetries.json`` (name -> BOP entry,
    mm) or a BOP ``models_info.json`` (id -> entry, for obj_NN files). The other parts' are
    detected from their meshes."""
    listed: dict[str, dict] = {}
    try:
        if (cad / 'models_info.json').is_file():
            by_id = json.loads((cad / 'models_info.json').read_text(encoding='utf-8'))
            listed = {p.name: by_id[str(p.obj_id)] for p in parts
                      if p.name.startswith('obj_') and str(p.obj_id) in by_id}
        if (cad / 'symmetries.json').is_file():
            listed.update(json.loads((cad / 'symmetries.json').read_text(encoding='utf-8')))
    except (OSError, ValueError) as error:
        raise TlessbotError(f'cannot read the symmetries listed in {cad}: {error}') from None
    return listed


def _lookalikes(out: Path, entries: list[dict]) -> None:
    """Each manifest entry's look-alike parts (by name), from the templates."""
    from tlessbot_ros.core.pose import TemplateDatabase

    db = TemplateDatabase.load(out / parts_io.TEMPLATES)
    names = {e['id']: e['name'] for e in entries}
    for entry in entries:
        obj = db.objects.get(entry['id'])
        entry['lookalikes'] = [names.get(i, str(i)) for i in (obj.lookalikes if obj else ())]


def self_check(out: Path, options: BuildOptions) -> list[dict]:
    """Simulate ``options.check_frames`` scenes of the parts seen by the rig, run the pipeline
    on them with the new files, and return one row per part (``out/self_check.md`` too; the
    evaluation's whole report stays in ``out/self_check/``)."""
    from tlessbot_ros.tools.support.observability import unseen_note

    config = ['--config', str(options.config)] if options.config else []
    models = str(out / parts_io.MODELS)
    report_dir = out / 'self_check'
    with tempfile.TemporaryDirectory(prefix='tlessbot_check_') as tmp:
        data = Path(tmp) / 'scenes'
        run_tool('simulate', '--models', models, '--out', str(data), '--frames',
                 str(options.check_frames), '--seed', str(options.seed + 7919), '--parts-min',
                 '3', '--depth-model', options.check_depth, *config)
        run_tool('evaluate', '--dataset', str(data), '--models', models, '--classifier',
                 str(out / parts_io.CLASSIFIER), '--templates', str(out / parts_io.TEMPLATES),
                 '--out', str(report_dir))
        report = json.loads((report_dir / 'report.json').read_text())
    manifest = json.loads((out / parts_io.MANIFEST).read_text())
    rows = []
    for part in manifest['parts']:
        stats = report['per_object'].get(str(part['id']), {'objects_gt': 0})
        rows.append({'name': part['name'], 'seen': stats['objects_gt'],
                     'pose': stats.get('recall_5cm5deg'), 'top1': stats.get('top1'),
                     'detected': stats.get('iou07_rate'),
                     'lookalikes': part.get('lookalikes', []),
                     'unseen': unseen_note(part.get('unseen_turns_5deg'))})
    summary = {'frames': report['frames'], 'pose': report['pose']['recall_5cm5deg'],
               'top1': report['recognition']['top1'],
               'detected': report['detection']['iou07_rate'],
               'false_pos_per_frame': report['detection']['false_pos_per_frame'],
               'depth_model': options.check_depth}
    (out / 'self_check.md').write_text(self_check_table(rows, summary) + '\n')
    manifest['self_check'] = summary
    parts_io.write_manifest(out, manifest)
    return rows


def self_check_table(rows: list[dict], summary: dict) -> str:
    """The self-check as Markdown: one row per part, then all parts."""
    def cell(value):
        return '-' if value is None else f'{value:.2f}'

    lines = ['| part | seen | 5 cm / 5° | top-1 | detected | look-alikes | turns not seen '
             '(px changed) | note |', '|---|---|---|---|---|---|---|---|']
    for r in rows:
        hard = r['pose'] is not None and r['pose'] < HARD_RECALL
        note = 'hard' if hard else ('not seen' if not r['seen'] else '')
        lines.append(f"| {r['name']} | {r['seen']} | {cell(r['pose'])} | {cell(r['top1'])} | "
                     f"{cell(r['detected'])} | {', '.join(r['lookalikes']) or '-'} | "
                     f"{r.get('unseen', '-')} | {note} |")
    depth = summary.get('depth_model', 'per_pixel').replace('_', '-')
    lines.append(f"| **all** ({summary['frames']} frames, {depth} depth) | | "
                 f"{cell(summary['pose'])} | "
                 f"{cell(summary['top1'])} | {cell(summary['detected'])} | | | false positives "
                 f"{cell(summary['false_pos_per_frame'])} / frame |")
    return '\n'.join(lines)


def observe_parts(cad: Path, options: BuildOptions) -> str:
    """``tlessbot parts observe``: the build's "turns the rig sees" step alone, on the CAD
    folder ``cad`` (same meshes and symmetries), as a Markdown table, one row per part."""
    from tlessbot_ros.tools.support.observability import record_unseen_turns, unseen_note
    from tlessbot_ros.tools.support.rig import load_rig

    rig = load_rig(options.config)
    meshes = read_meshes(parts_io.cad_parts(cad), options.units)
    with tempfile.TemporaryDirectory(prefix='tlessbot_observe_') as tmp:
        entries = _write_models(cad, Path(tmp), meshes)
        started = time.perf_counter()
        record_unseen_turns(Path(tmp) / parts_io.MODELS, entries, rig, quiet=True)
        took = time.perf_counter() - started
    lines = ['| part | size (mm) | symmetry | turns not seen (px changed) |',
             '|---|---|---|---|']
    lines += [f"| {e['name']} | {' x '.join(f'{v:.0f}' for v in e['size_mm'])} | "
              f"{e['symmetry']} | {unseen_note(e['unseen_turns_5deg'])} |" for e in entries]
    return '\n'.join(lines) + f'\n\n{len(entries)} parts in {took:.1f} s'


def build_parts(cad: Path, out: Path, options: BuildOptions, *, check: bool = True,
                classifier: bool = True, warm: bool = True) -> parts_io.PartsFolder | None:
    """Build the parts folder ``out`` from the CAD folder ``cad`` (see the module docstring);
    prints each step's time (the templates' beside the classifier's: they run at once) and
    the whole build's. A folder left by a failed build is removed. Without ``classifier``
    (only templates: ``evaluate --oracle boxes+classes``) it returns None. ``warm``: build the
    pose node's start-up caches of the templates too."""
    from tlessbot_ros.tools.support.rig import load_rig

    rig = load_rig(options.config)   # refused before minutes of work
    cad_list = parts_io.cad_parts(cad)
    if len(cad_list) < 2:
        raise TlessbotError(f'{cad} holds {len(cad_list)} part; a parts set needs at least 2')
    meshes = read_meshes(cad_list, options.units)
    if out.exists() and any(out.iterdir()):
        if not (out / parts_io.MANIFEST).is_file():
            raise TlessbotError(f'{out} exists and is not a parts folder: choose another --out')
        shutil.rmtree(out)
    out.mkdir(parents=True)
    manifest = {'units': options.units, 'recipe': options.recipe or 'train defaults',
                'smoothed_share': options.smoothed_share,
                'fingerprint': parts_io.cad_fingerprint(cad_list, units=options.units),
                'rig': parts_io.rig_summary(rig), 'source': str(cad)}
    started = time.perf_counter()
    try:
        times = _run_steps(cad, out, options, manifest, meshes, check=check and classifier,
                           classifier=classifier, warm=warm)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    wall = time.perf_counter() - started
    manifest = json.loads((out / parts_io.MANIFEST).read_text())
    manifest['build_s'] = {k: round(v, 1) for k, v in times.items()}
    manifest['build_wall_s'] = round(wall, 1)
    parts_io.write_manifest(out, manifest)
    print(f'{len(cad_list)} parts -> {out} in {wall:.0f} s ('
          + ', '.join(f'{k} {v:.0f} s' for k, v in times.items())
          + '; the templates beside the classifier)')
    return parts_io.open_parts_folder(out, rig=rig) if classifier else None


def _run_steps(cad: Path, out: Path, options: BuildOptions, manifest: dict, meshes: dict,
               *, check: bool, classifier: bool, warm: bool) -> dict[str, float]:
    """The build's steps, timed: {step: s}. The templates are made in a child process while
    the classifier is trained."""
    import threading

    from tqdm import tqdm

    from tlessbot_ros.tools.support.observability import record_unseen_turns
    from tlessbot_ros.tools.support.rig import load_rig

    config = ['--config', str(options.config)] if options.config else []
    names = ['meshes + symmetries', 'turns the rig sees', 'templates',
             'classifier' if classifier else None, 'manifest',
             STARTUP_CACHES if warm else None, 'self-check' if check else None]
    times: dict[str, float] = {}
    with tqdm(total=sum(n is not None for n in names), desc='parts build', unit='step') as bar, \
            tempfile.TemporaryDirectory(prefix='tlessbot_build_') as tmp:
        def timed(name: str, step) -> None:
            bar.set_postfix_str(name)
            t0 = time.perf_counter()
            step()
            times[name] = time.perf_counter() - t0
            tqdm.write(f'[parts build] {name}: {times[name]:.1f} s')
            bar.update()

        timed('meshes + symmetries',
              lambda: manifest.update(parts=_write_models(cad, out, meshes)))
        timed('turns the rig sees', lambda: record_unseen_turns(
            out / parts_io.MODELS, manifest['parts'], load_rig(options.config)))
        log = Path(tmp) / 'templates.log'
        t0 = time.perf_counter()
        templates = start_tool('templates', '--models', str(out / parts_io.MODELS), '--out',
                               str(out / parts_io.TEMPLATES), *config, log=log)
        ended: list[float] = []
        watcher = threading.Thread(target=lambda: ended.append(
            (templates.wait(), time.perf_counter())[1]), daemon=True)
        watcher.start()
        try:
            if classifier:
                timed('classifier', lambda: _train_classifier(out, options,
                                                              manifest['fingerprint']))
        except BaseException:
            templates.kill()
            raise
        finish_tool('templates', templates, log)
        watcher.join()
        times['templates'] = ended[0] - t0
        tqdm.write(f'[parts build] templates: {times["templates"]:.1f} s (beside the '
                   'classifier)')
        bar.update()
        timed('manifest', lambda: (_lookalikes(out, manifest['parts']),
                                   parts_io.write_manifest(out, manifest)))
        if warm:   # the pose node's first start on this folder then reads them
            timed(STARTUP_CACHES, lambda: run_tool('warm-up', '--templates',
                                                   str(out / parts_io.TEMPLATES)))
        if check:
            timed('self-check', lambda: print(self_check_table(
                self_check(out, options), json.loads(
                    (out / parts_io.MANIFEST).read_text())['self_check'])))
    return times


# What the templates of a parts folder are made by: a change to any of these files builds the
# cached parts folders again (the classifier keeps its own cache, keyed by its recipe).
TEMPLATE_CODE = ('core/pose', 'core/common', 'io', 'tools/commands/templates.py')


def template_code_fingerprint(root: Path | None = None) -> str:
    """SHA-256 (hex) of the Python sources under :data:`TEMPLATE_CODE` of the package at
    ``root`` (this one by default), names and bytes, in a fixed order."""
    root = root or Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for entry in TEMPLATE_CODE:
        path = root / entry
        files = sorted(path.rglob('*.py')) if path.is_dir() else [path] * path.is_file()
        for file in files:
            digest.update(file.relative_to(root).as_posix().encode() + b'\0')
            digest.update(file.read_bytes())
    return digest.hexdigest()


def parts_cache_name(cad: Path, options: BuildOptions, *, code: str | None = None) -> str:
    """The cache folder's name of ``cad``'s parts: the CAD files' content and units, the code
    that makes templates (``code``: its fingerprint, this package's by default), the recipe
    and the share of smoothed training depth."""
    fingerprint = parts_io.cad_fingerprint(parts_io.cad_parts(cad), units=options.units)
    code = code or template_code_fingerprint()
    smoothed = f'_smoothed{options.smoothed_share:g}' if options.smoothed_share else ''
    return f'{fingerprint[:16]}-{code[:8]}_{options.recipe or "defaults"}{smoothed}'


def cached_parts(cad: Path, options: BuildOptions, *, classifier: bool = True
                 ) -> parts_io.PartsFolder:
    """The parts folder of ``cad`` built without the self-check (and without the classifier
    unless ``classifier``), kept in the start-up cache by :func:`parts_cache_name`: built once,
    reused after, built again when the code that makes templates changed."""
    from tlessbot_ros.io.cache import cache_dir

    out = cache_dir() / 'parts' / parts_cache_name(cad, options)
    folder = parts_io.PartsFolder(out, {})
    wanted = [out / parts_io.MANIFEST, folder.templates] + [folder.classifier] * classifier
    if all(path.is_file() for path in wanted):
        print(f'using the parts built before from the same CAD files: {out}')
    else:
        print(f'building the {"classifier and " * classifier}templates of {cad} into {out} '
              '(once)')
        # built aside and moved in whole: a second evaluate started meanwhile on the same CAD
        # builds its own copy instead of finding this one half-built
        building = out.with_name(f'.{out.name}.{os.getpid()}.building')
        try:
            build_parts(cad, building, options, check=False, classifier=classifier,
                        warm=False)
            _move_in(building, out, [path.name for path in wanted])
        finally:
            shutil.rmtree(building, ignore_errors=True)
    return folder


def _move_in(built: Path, out: Path, needed: list[str]) -> None:
    """Rename the finished cache folder ``built`` to ``out``; an ``out`` that lacks one of
    the ``needed`` files is replaced, a complete one (another process's) is kept."""
    if out.exists() and not all((out / name).is_file() for name in needed):
        shutil.rmtree(out, ignore_errors=True)
    try:
        built.rename(out)
    except OSError:
        if not all((out / name).is_file() for name in needed):
            raise
