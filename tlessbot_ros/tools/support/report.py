"""report.md (the paper's Table 1 and Table 3 shapes) and PNG plots of an evaluation report."""
from __future__ import annotations

from pathlib import Path

from tlessbot_ros.core.common.names import part_name
from tlessbot_ros.tools.support.eval_breakdown import markdown as breakdown_lines

_POSE_COLUMNS = (('recall_5cm5deg', '5 cm / 5°'), ('recall_1cm5deg', '1 cm / 5°'),
                 ('recall_vsd03', 'VSD < 0.3'), ('recall_adds01d', 'ADD-S < 0.1 d'),
                 ('mssd_recall', 'AR MSSD'), ('mspd_recall', 'AR MSPD'))
_STAGES = ('segmentation', 'classification', 'pose', 'frame')
# shown in report.md when measured, not plotted with the stages
_PER_PART_TIMES = (('pose_per_part', 'pose, per part fitted'),
                   ('table_plane', 'table plane, all views'))


def cell(value) -> str:
    """A table cell: 3 decimals for a float, 'n/a' for None."""
    if value is None:
        return 'n/a'
    return f'{value:.3f}' if isinstance(value, float) else str(value)


def report_names(report: dict) -> dict[int, str]:
    """{id: name} of a report's parts (its ``names``; obj_NN for the parts it does not list)."""
    return {int(k): str(v) for k, v in report.get('names', {}).items()}


def markdown(report: dict) -> str:
    """The report as Markdown: summary, per-object recall (Table 1), stage times (Table 3);
    parts named by the report's ``names``."""
    names = report_names(report)
    lines = ['# Evaluation report', '',
             f'- dataset: `{report.get("dataset", "?")}` ({report.get("split", "?")})',
             f'- mode: {report.get("mode", "?")}',
             f'- frames: {report["frames"]}, parts with visib_fract >= 0.3: '
             f'{report["objects_gt"]}',
             f'- detection: IoU >= 0.7 rate {cell(report["detection"]["iou07_rate"])}, '
             f'false positives per frame {cell(report["detection"]["false_pos_per_frame"])}, '
             f'duplicates per frame {cell(report["detection"].get("duplicates_per_frame"))}',
             '- false parts outside the scored camera per frame (poses outside its image near '
             'no part: in no false-positive figure here) '
             f'{cell(report["detection"].get("unscored_false_parts_per_frame"))}',
             f'- recognition top-1: {cell(report["recognition"]["top1"])}; parts called '
             f'unknown {cell(report["recognition"].get("unknown_rate"))}; regions that are no '
             f'part named as one (false positives) per frame '
             f'{cell(report["recognition"].get("false_pos_per_frame"))}, regions called '
             f'unknown per frame {cell(report["recognition"].get("unknown_per_frame"))}']
    if 'run_time_s' in report:
        lines.append(f'- run time: {report["run_time_s"]:.1f} s')
    lines += ['', '## Pose recall per object (Table 1 shape)', '',
              '| object | parts | detected (IoU ≥ 0.7) | top-1 | '
              + ' | '.join(name for _, name in _POSE_COLUMNS) + ' |',
              '|---' * (4 + len(_POSE_COLUMNS)) + '|']
    rows = [(part_name(int(k), names), v) for k, v in report['per_object'].items()]
    rows.append(('**all**', {**report['pose'], 'objects_gt': report['objects_gt'],
                             'iou07_rate': report['detection']['iou07_rate'],
                             'top1': report['recognition']['top1']}))
    for name, m in rows:
        lines.append(f'| {name} | {m.get("objects_gt", 0)} | {cell(m.get("iou07_rate"))} | '
                     f'{cell(m.get("top1"))} | '
                     + ' | '.join(cell(m.get(key)) for key, _ in _POSE_COLUMNS) + ' |')
    if report['detection'].get('breakdown'):
        lines += breakdown_lines(report['detection']['breakdown'], report['frames'], names)
    lines += ['', '## Time per stage, median ms per frame (Table 3 shape)', '',
              '| stage | ms |', '|---|---|']
    for stage in _STAGES:
        lines.append(f'| {stage} | {cell(report["timing_ms"].get(stage))} |')
    for key, name in _PER_PART_TIMES:
        if report['timing_ms'].get(key) is not None:
            lines.append(f'| {name} | {cell(report["timing_ms"][key])} |')
    return '\n'.join(lines) + '\n'


def plot(report: dict, out: Path) -> list[Path]:
    """recall_per_object.png (and timing.png when stage times exist); returns the paths."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import numpy as np

    written = []
    objects = list(report['per_object'])
    keys = [(k, n) for k, n in _POSE_COLUMNS[:4]
            if any(report['per_object'][o].get(k) is not None for o in objects)]
    if objects and keys:
        fig, ax = plt.subplots(figsize=(max(6, 0.6 * len(objects) + 2), 4))
        width = 0.8 / len(keys)
        x = np.arange(len(objects))
        for i, (key, name) in enumerate(keys):
            values = [report['per_object'][o].get(key) or 0.0 for o in objects]
            ax.bar(x + i * width, values, width, label=name)
        names = report_names(report)
        ax.set_xticks(x + 0.4 - width / 2, [part_name(int(o), names) for o in objects],
                      rotation=45)
        ax.set_ylim(0, 1)
        ax.set_ylabel('recall')
        ax.set_title('Pose recall per object')
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = out / 'recall_per_object.png'
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)
    stages = [(s, report['timing_ms'].get(s)) for s in _STAGES]
    stages = [(s, v) for s, v in stages if v is not None]
    if stages:
        fig, ax = plt.subplots(figsize=(5, 3))
        ax.barh([s for s, _ in stages], [v for _, v in stages])
        ax.set_xlabel('median ms per frame')
        ax.set_title('Time per stage')
        fig.tight_layout()
        path = out / 'timing.png'
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)
    return written


def write_report(report: dict, out: Path) -> None:
    """Write report.md and the PNG plots into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    (out / 'report.md').write_text(markdown(report), encoding='utf-8')
    plot(report, out)
