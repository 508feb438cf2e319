"""Running a command over many files: the batch layer above the pipelines.

* :mod:`rawsim.run.batch`: discovery, output paths, per-file seeds, sharding, the
  local pool of workers, the summary;
* :mod:`rawsim.run.jobs`: one job on one file (skip, refuse, fail or finish, with
  no partial outputs) and how signals stop it;
* :mod:`rawsim.run.ray_executor`: the same jobs as tasks of a Ray cluster.

The pipelines (:mod:`rawsim.pipelines`) know nothing of batches: a job is given an
:class:`~rawsim.io.task.Task` and returns its record.
"""
