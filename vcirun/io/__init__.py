"""Files: a sweep's results file (one HDF5 file per sweep, layout in docs/reference/results_schema.md), its
journal, and the views the experiments and the user read it through.

Module        What it owns
------------  -----------------------------------------------------------------------------------
errors        StorageError, the one error of results files, and the one-line texts of its messages
checks        the file's identity (FORMAT, SCHEMA_VERSION, LIBVER); when a run or reference group is
              trusted (run_problem, reference_problem, scan_groups); the output path (resolve_output)
provenance    versions, git commit, platform and time stamps stored as root attributes
batches       many runs (or references) in one HDF5 group: pack, write, read, check, delete items
legacy_text   variable-length text of files of earlier versions: read first in a child with a deadline,
              rewritten fixed-length by a resume
journal       the binary journal beside the file: record format, read_journal, applying it
durable       fsync, space reservation, HDF5 writes in a forked child, atomic replace by a copy
lock          the single-writer lock (an flock on a hidden sibling)
compaction    folding a running session's journal into the file from a forked child
writer        ResultsWriter: a sweep session (acquire, start, commit, finish) and its safety model
reader        read_results, Results, RunInfo, load_trajectory, load_reference, find_newest_results
results       vcirun.open_results: a results file as one labelled table (collect, reference_note)
xr            the xarray Dataset/DataArray classes open_results returns

The run-group codec (attribute encoding, a Trajectory as a group) is vcirun.run.trajectory_files,
shared with Trajectory.save.
"""
