"""Odometry over an archive of recordings: ``line_odom batch INPUTS --out DIR``.

Each recording (any format :func:`line_odom.readers.guess_format` recognizes) is one task that runs
:func:`line_odom.replay.replay` in-process (deterministic) and writes replay's outputs to ``DIR/<label>/``. Tasks
run on Dask's distributed engine: ``workers=N`` starts a ``LocalCluster`` of N single-threaded worker processes for
the run, ``cluster=ADDRESS`` submits the same tasks to an existing scheduler (whose workers must see INPUTS and DIR
at the same paths and run the same line_odom).

Safety: a task writes into ``DIR/.batch_tmp/`` and renames its finished output directory to ``DIR/<label>`` in one
step, so an interrupted run leaves complete outputs or none. ``batch.json`` in an output directory records the
task it ran (input, parameters, overrides, frames); outputs whose record matches the task are skipped unless
``force``. A recording that raises is a failed row with its one-line error; a task whose worker process dies is
submitted once more, then reported as failed.

``DIR/summary.csv``, ``summary.md`` and ``summary.png`` hold one row per recording (status, seconds, metrics, the
machine and commit that produced it), mean / median / worst per metric and a bar chart of the per-recording RPE.

Modules: recordings (folders and manifests), task (one recording), scheduling (Dask), summary, outputs (the output
folder's files), run (run_batch).
"""
from line_odom.batch.outputs import LOCK, RECORD, REPLAY_OUTPUTS, SUMMARY_CSV, SUMMARY_MD, SUMMARY_PLOT, TMP_DIR
from line_odom.batch.recordings import MANIFEST_FIELDS, Recording, detect, discover, read_manifest, recordings_from
from line_odom.batch.run import BatchProgress, BatchResult, run_batch
from line_odom.batch.scheduling import DEPENDENCY_HINT, connect, execute, local_cluster
from line_odom.batch.summary import aggregates, plot_summary, summary_csv, summary_md, write_summary
from line_odom.batch.task import one_line_error, provenance, run_recording

__all__ = ["LOCK", "RECORD", "REPLAY_OUTPUTS", "SUMMARY_CSV", "SUMMARY_MD", "SUMMARY_PLOT", "TMP_DIR", "MANIFEST_FIELDS",
           "Recording", "detect", "discover", "read_manifest", "recordings_from", "BatchProgress", "BatchResult",
           "run_batch", "DEPENDENCY_HINT", "connect", "execute", "local_cluster", "aggregates", "plot_summary",
           "summary_csv", "summary_md", "write_summary", "one_line_error", "provenance", "run_recording"]
