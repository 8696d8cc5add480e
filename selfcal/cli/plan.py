"""Predict the peak memory and the seconds per iteration of adjusting a block, before any adjustment."""
from __future__ import annotations

import argparse

from .options import ap_option, grid_option
from .outcome import finish, progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("block", metavar="BLOCK", help="block folder (DESIGN.md §3)")
    ap_option(parser)
    grid_option(parser)
    parser.add_argument("--scheduler", metavar="SPEC",
                        help="plan selfcal adjust --scheduler SPEC: the client's peak and each worker's ('local', "
                             "'local:N' or a running scheduler's address, asked for its workers)")


def _table(plan, available_mb: float, workers: int | None = None) -> str:
    """The plan as a short table: component, MB, seconds per iteration."""
    rows = [f"{'component':<16}{'MB':>9}{'s/iter.':>9}"]
    names = list(dict.fromkeys([*plan.memory_mb, *plan.seconds]))
    for name in names:
        mb = plan.memory_mb.get(name)
        s = plan.seconds.get(name)
        rows.append(f"{name.replace('_', ' '):<16}{'' if mb is None else f'{mb:.0f}':>9}"
                    f"{'' if s is None else f'{s:.3f}':>9}")
    rows.append(f"{'peak / total':<16}{plan.peak_mb:>9.0f}{plan.seconds_per_iteration:>9.3f}   (one adjustment)")
    rows.append(f"{'selfcal adjust':<16}{plan.workflow_peak_mb:>9.0f}{'':>9}   (its default tested workflow)")
    if workers:
        rows.append(f"{'client':<16}{plan.client_peak_mb(workers):>9.0f}{'':>9}   (one adjustment "
                    f"with --scheduler; its tested workflow as selfcal adjust's above)")
        rows.append(f"{'each worker':<16}{plan.worker_peak_mb(workers):>9.0f}{'':>9}   (of {workers}; "
                    f"{plan.worker_peak_mb(workers, workflow=True):.0f} MB in the tested workflow)")
    sizes = plan.sizes
    rows.append(f"{sizes.n_images} images, {sizes.n_points} points, {sizes.n_observations} observations, "
                f"{sizes.n_theta} unknowns in the reduced system ({sizes.image_pairs} image pairs): "
                f"{plan.factorisation} factorisation, {plan.covariance}; AP model {plan.ap_model}")
    rows.append(f"memory available now: {available_mb:.0f} MB")
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    from ..io import read_block
    from ..workflows.plan import available_mb, check_fits, plan_block

    workers, local = None, False
    if args.scheduler:
        from ..workflows.cluster import scheduler_workers
        workers, local = scheduler_workers(args.scheduler)
    progress(f"reading {args.block} ...")
    block = read_block(args.block)
    plan = plan_block(block, args.ap, args.grid)
    available = available_mb()
    figures = {**plan.as_dict(), "available_mb": available}
    if workers:
        figures |= {"scheduler": args.scheduler, "workers": workers, "worker_peak_mb": plan.worker_peak_mb(workers),
                    "worker_workflow_peak_mb": plan.worker_peak_mb(workers, workflow=True),
                    "client_peak_mb": plan.client_peak_mb(workers),
                    "client_workflow_peak_mb": plan.client_peak_mb(workers, workflow=True)}
    # a local cluster's workers share this machine with the client; a scheduler's are elsewhere
    check_fits(plan, available, workers=workers if local else None)
    return finish(args, _table(plan, available, workers), figures)
