"""Results: the files a run writes, reading them back, and what is made of them.

* `mikasa_bench.results.files`: file names of a run directory and atomic writes;
* `mikasa_bench.results.summary`: the per-task result and the summary (benchmark.md §7);
* `mikasa_bench.results.store`: `RunStore`, the writer of a run directory (journal, resume);
* `mikasa_bench.results.run_data`: `load_run` reads a finished run back (`RunData`);
* `mikasa_bench.results.report`, `mikasa_bench.results.compare`: the text table, the
  Markdown/HTML report and the per-task comparison of two runs
  (`mikasa_bench.results.text` formats their tables);
* `mikasa_bench.results.validity` and `mikasa_bench.results.leaks`: the validity table
  of the reference policies against chance, and the list of answer leaks found.

Import names from those modules; this package file imports nothing.
"""
