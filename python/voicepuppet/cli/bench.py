"""``voicepuppet bench SUITE --json FILE``: our kernels side by side with a peer.

The ``bench`` verb (see :mod:`voicepuppet.bench.runner` for what it drives).
"""

from __future__ import annotations


def _run(args) -> int:
    from voicepuppet.bench.runner import SUITES, machine_info, print_table, run_suite, write_json_atomic
    from voicepuppet.cli.main import UserError

    if args.suite not in SUITES:
        raise UserError(f"unknown suite {args.suite!r}; choose one of {', '.join(sorted(SUITES))}")
    cases = run_suite(args.suite, quick=args.quick, repeats=args.repeats)
    print_table(cases)
    if args.json:
        write_json_atomic(args.json, {"suite": args.suite, "machine": machine_info(), "cases": cases})
        print(f"wrote {args.json}")
    return 0


def add_parser(sub) -> None:
    from voicepuppet.bench.runner import SUITES

    p = sub.add_parser("bench", help="benchmark a kernel family against its peer",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("suite", choices=sorted(SUITES), help="which benchmark suite")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON (schema of DESIGN.md)")
    p.add_argument("--repeats", type=int, default=3, help="timed repeats per case (median; default 3)")
    p.add_argument("--quick", action="store_true", help="small sizes, for a smoke run")
    p.set_defaults(func=_run)
