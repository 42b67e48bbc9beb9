"""``hybridmarl reproduce``: the paper's Table 1, Table 2 and Fig. 3 as a grid of independent,
resumable tasks, run on a Ray cluster or on this machine.

- :mod:`~hybridmarl.reproduce.protocol`: the evaluation protocol, the budgets, the paper's numbers;
- :mod:`~hybridmarl.reproduce.grid`: the grid as data (tasks with stable keys, table cells);
- :mod:`~hybridmarl.reproduce.worker`: one task, in its own process;
- :mod:`~hybridmarl.reproduce.executors`: local child processes or Ray tasks;
- :mod:`~hybridmarl.reproduce.driver`: the output folder, task states, the run loop, progress;
- :mod:`~hybridmarl.reproduce.outputs`: tables, Fig. 3 and the HTML report.

Nothing here imports JAX at module level: the driver stays free of it, and each task process
loads it itself.
"""
