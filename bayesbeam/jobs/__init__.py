"""Runs of many fits: tasks, executor, demo (the main job), benchmark.

Runs of many fits: fit tasks, the process-pool / Dask executor, the demo (main job)
and its summary, the forward-model benchmark.

Layer: above :mod:`bayesbeam.report`.
"""

from bayesbeam._util import lazy_exports

_EXPORTS = {
    "beam_of": ".summary",
    "beam_summary": ".summary",
    "bench_beam": ".bench",
    "bench_params": ".bench",
    "conclusions_text": ".summary",
    "DATA_DIR": ".demo",
    "DEFAULT_SETTINGS": ".tasks",
    "DEMO_SETTINGS": ".demo",
    "DemoError": ".demo",
    "DIAGNOSIS_SETTINGS": ".demo",
    "ExecutorError": ".tasks",
    "find_data": ".demo",
    "fit_tasks": ".tasks",
    "FitTask": ".tasks",
    "format_bench": ".bench",
    "format_table": ".summary",
    "list_trials": ".demo",
    "load_score": ".executor",
    "make_executor": ".executor",
    "map_tasks": ".executor",
    "MODELS": ".demo",
    "QUICK_DIAGNOSIS": ".demo",
    "QUICK_SETTINGS": ".demo",
    "Replication": ".demo",
    "run_bench": ".bench",
    "run_demo": ".demo",
    "run_diagnosis_task": ".demo",
    "run_fit_task": ".tasks",
    "run_fits": ".executor",
    "run_replication": ".demo",
    "task_key": ".tasks",
    "TaskOutcome": ".tasks",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
