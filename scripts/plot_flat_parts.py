"""Bar plot and Markdown table of `tlessbot evaluate` reports side by side (docs/bench).

    python scripts/plot_flat_parts.py OUT.png LABEL=REPORT.json [LABEL=REPORT.json ...]
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

MEASURES = (('5 cm / 5°', lambda r: r['pose']['recall_5cm5deg']),
            ('top-1', lambda r: r['recognition']['top1']),
            ('detection IoU ≥ 0.7', lambda r: r['detection']['iou07_rate']),
            ('false positives / frame', lambda r: r['detection']['false_pos_per_frame']))


def main(argv: list[str]) -> int:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import numpy as np

    out, pairs = Path(argv[0]), [a.split('=', 1) for a in argv[1:]]
    reports = [(label, json.loads(Path(path).read_text())) for label, path in pairs]
    print('| set | ' + ' | '.join(m for m, _ in MEASURES) + ' | parts |')
    print('|---|' + '---|' * (len(MEASURES) + 1))
    for label, r in reports:
        print(f'| {label} | ' + ' | '.join(f'{f(r):.3f}' if f(r) is not None else 'n/a'
                                          for _, f in MEASURES) + f' | {r["objects_gt"]} |')
    fig, ax = plt.subplots(figsize=(9, 4))
    width = 0.8 / len(reports)
    x = np.arange(len(MEASURES))
    for k, (label, r) in enumerate(reports):
        values = [f(r) or 0.0 for _, f in MEASURES]
        bars = ax.bar(x + (k - (len(reports) - 1) / 2) * width, values, width, label=label)
        ax.bar_label(bars, fmt='%.2f', fontsize=7)
    ax.set_xticks(x, [m for m, _ in MEASURES])
    ax.axhline(0.9, color='grey', lw=0.8, ls='--')
    ax.axhline(0.2, color='grey', lw=0.8, ls=':')
    top = max(f(r) or 0.0 for _, r in reports for _, f in MEASURES)
    ax.set_ylim(0, max(1.15, 1.1 * top))
    ax.legend(fontsize=8, loc='upper right')
    ax.set_title('Flat parts and T-LESS, same simulator settings (12 two-view frames each)')
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return 0


if __name__ == '__main__':
    raise SystemExit(main(sys.argv[1:]))
