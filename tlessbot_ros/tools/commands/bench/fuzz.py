"""Garbage at rate: malformed messages at 100 Hz on every input topic while good frames flow.

    tlessbot bench fuzz --duration 60

The demo bag is replayed in a loop (restamped) at ``--fps`` through the three perception nodes
(processes). After ``--clean`` seconds a garbage process publishes on every input topic of
every stage (cameras, the localiser's relays, labels, classes, frame outcomes) at ``--rate``
messages/s each for ``--duration`` seconds (:mod:`~tlessbot_ros.tools.support.garbage`), then
the replay goes on clean for ``--after`` seconds. Garbage stamps never come near a good frame's
stamp. Printed: per node whether it is alive, RSS / open fds / threads before and after the
garbage (RSS trend during it), its /diagnostics counters before and after; per phase the good
frames answered and their parts within 5 cm / 5 deg of the ground truth.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_MODELS_INFO, DEFAULT_TEMPLATES
from tlessbot_ros.tools.support.defaults import DEFAULT_BAG


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', default=str(DEFAULT_BAG), help='good bag with ground truth')
    parser.add_argument('--duration', type=float, default=60.0, help='seconds of garbage')
    parser.add_argument('--clean', type=float, default=30.0,
                        help='seconds of good frames alone before the garbage')
    parser.add_argument('--after', type=float, default=15.0,
                        help='seconds of good frames alone after the garbage')
    parser.add_argument('--fps', type=float, default=2.0, help='good frames per second')
    parser.add_argument('--rate', type=float, default=100.0,
                        help='garbage messages per second on each input topic')
    parser.add_argument('--frame-rate', type=float, default=1.0,
                        help='coherent garbage two-view frames per second (one message '
                             "corrupted), which reach the stages' processing")
    parser.add_argument('--huge-period', type=float, default=1.0,
                        help='seconds between 4K images (on one topic after the other)')
    parser.add_argument('--input-depth', type=int, default=None,
                        help="the stages' input_depth (DDS history per input topic; default: "
                             "the nodes' own)")
    parser.add_argument('--jump-confirmations', type=int, default=None,
                        help="every stage's sync.jump_confirmations (above 0 a stray stamp is "
                             "dropped instead of emptying every queue; default: the nodes' "
                             "own, 4 on the camera topics and 0 behind the localiser's relay)")
    parser.add_argument('--classifier', default=str(DEFAULT_CLASSIFIER))
    parser.add_argument('--templates', default=str(DEFAULT_TEMPLATES))
    parser.add_argument('--models-info', default=str(DEFAULT_MODELS_INFO))
    parser.add_argument('--config', default=None)
    parser.add_argument('--out', default=None, help='also write the Markdown tables here')


def node_table(fuzz) -> str:
    """Per node: RSS, fds and threads before / after the garbage and at the end, the RSS
    trend during it, and its /diagnostics counters before / after."""
    from tlessbot_ros.tools.commands.bench.graph import rss_trend_mb_per_min
    from tlessbot_ros.tools.support.fuzz_run import NODE_COUNTERS, garbage_samples, sample_at

    result = fuzz.result
    lines = ['| node | alive | RSS MiB before -> after garbage -> end (trend during, MiB/min)'
             ' | fds before -> after | threads before -> after | '
             + ' | '.join(f'{c} before -> after' for c in NODE_COUNTERS) + ' |',
             '|' + '---|' * (5 + len(NODE_COUNTERS))]
    for node in sorted(result.rss_mb_samples):
        rss, fds = result.rss_mb_samples[node], result.fd_samples[node]
        threads = result.thread_samples[node]

        def around(samples):
            return (sample_at(fuzz, samples, fuzz.garbage_started_ns),
                    sample_at(fuzz, samples, fuzz.garbage_ended_ns))
        (rss0, rss1), (fd0, fd1), (th0, th1) = around(rss), around(fds), around(threads)
        trend = rss_trend_mb_per_min(garbage_samples(fuzz, rss))
        before, after = fuzz.diagnostics_before.get(node, {}), result.diagnostics.get(node, {})
        lines.append(f'| {node} | yes | {rss0:.0f} -> {rss1:.0f} -> '
                     f'{result.rss_mb_end.get(node, float("nan")):.0f} ({trend:+.1f}) | '
                     f'{fd0} -> {fd1} | {th0} -> {th1} | '
                     + ' | '.join(f"{before.get(c, '?')} -> {after.get(c, '?')}"
                                  for c in NODE_COUNTERS) + ' |')
    return '\n'.join(lines)


def phase_table(scores) -> str:
    lines = ['| phase | good frames sent | answered (a pose came back) | parts within '
             "5 cm / 5 deg | of the answered frames' parts |", '|---|---|---|---|---|']
    for phase, score in scores.items():
        lines.append(f'| {phase} | {score.frames} | {score.answered} '
                     f'({100 * score.answered_share:.0f} %) | {score.correct} / {score.parts} '
                     f'({100 * score.recall:.0f} %) | {score.answered_correct} / '
                     f'{score.answered_parts} ({100 * score.answered_recall:.0f} %) |')
    return '\n'.join(lines)


def sent_summary(fuzz) -> str:
    sent = fuzz.sent
    seconds = max(sent.get('seconds', 0.0), 1e-9)
    per_topic = sent.get('per_topic', {})
    rates = [count / seconds for count in per_topic.values()]
    kinds = ', '.join(f'{kind} {count}' for kind, count in sorted(sent.get('per_kind',
                                                                          {}).items()))
    return (f'garbage: {sum(per_topic.values())} messages on {len(per_topic)} topics in '
            f'{seconds:.1f} s ({min(rates, default=0):.0f}-{max(rates, default=0):.0f} per s '
            f'per topic), {sent.get("frames", 0)} coherent corrupted frames; by kind: {kinds}')


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.io.config import default_config_path
    from tlessbot_ros.tools.support.fuzz_run import run_fuzz, score_phases
    from tlessbot_ros.tools.support.models_info import load_symmetries

    config = Path(args.config) if args.config else default_config_path()
    fuzz = run_fuzz(args.bag, config=config, fps=args.fps, clean_s=args.clean,
                    garbage_s=args.duration, after_s=args.after, rate_hz=args.rate,
                    frame_rate_hz=args.frame_rate, huge_period_s=args.huge_period,
                    ros_args=['-p', f'model_path:={args.classifier}',
                              '-p', f'templates_path:={args.templates}',
                              *(['-p', f'input_depth:={args.input_depth}']
                                if args.input_depth else []),
                              *(['-p', f'sync.jump_confirmations:={args.jump_confirmations}']
                                if args.jump_confirmations is not None else [])])
    scores = score_phases(fuzz, args.bag, load_symmetries(args.models_info))
    text = '\n\n'.join([sent_summary(fuzz), node_table(fuzz), phase_table(scores)])
    print(text)
    if args.out:
        Path(args.out).write_text(text + '\n')
    return 0
