"""Simulation campaigns: many simulated drives at once, and what is made of them.

A campaign (``bench campaign C.yaml``; docs/campaigns.md) runs a grid or random sample of
scenarios on the simulator (``sim_fallback.run_scenario``, in-process or on a Dask
cluster), keeps the numbers in Parquet, judges them against limits and writes a report;
``--replay N --full`` replays one run as a full bench run. The paper reproduction
(tools/reproduce_paper.py, docs/reproduction.md) is a set of campaigns rendered by
:func:`render`.

It sits above the bench (it reads campaign files as the bench reads sequences, shares its
report's plotly asset and replays runs through it) and below nothing but the command line.
"""

from ._campaign import (
    BASE_EXTRACTOR,
    BASE_MOTOR,
    Axis,
    Campaign,
    CampaignError,
    ResultsError,
    SchedulerError,
    add_parser,
    cmd,
    judge,
    load_campaign,
    load_results,
    parse_campaign,
    peak_rss_mb,
    replay_command,
    resolve_run,
    run_campaign,
    run_campaigns,
    start_local_cluster,
    warm_worker,
    warm_writer,
)
from ._reproduction import read_results, render

__all__ = [
    "add_parser", "Axis", "BASE_EXTRACTOR", "BASE_MOTOR", "Campaign", "CampaignError", "cmd",
    "judge", "load_campaign", "load_results", "parse_campaign", "peak_rss_mb", "read_results",
    "render", "replay_command", "resolve_run", "ResultsError", "run_campaign", "run_campaigns",
    "SchedulerError", "start_local_cluster", "warm_worker", "warm_writer",
]
