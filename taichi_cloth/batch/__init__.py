"""Batch fitting (`python -m taichi_cloth batch SPEC.toml`, docs/batch.md): garments x bodies x materials, one job
each, on a process pool or a Ray cluster; resumable; a results table, a contact sheet, a summary.

Modules: spec (the batch spec file), jobs (the job list, scene dicts and keys), worker (one job in a process),
figures (a finished job's status and figures), schedule (the loop: retries, timeouts, progress), pool (the process
pool), cluster (the Ray backend, the `cluster` extra), table (Parquet and CSV), sheet (the contact sheet), cli (the
`batch` subcommand). Nothing is imported here: the command line loads cli, a worker process loads worker.
"""
