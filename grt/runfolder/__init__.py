"""Run folders: what a run, a training and a study leave, and how they continue.

- :mod:`grt.runfolder.record` (lowest): the record of a start (``run_config.yaml``, its format version and
  :func:`~grt.runfolder.record.migrate`), which folder is what, and the lines that name a folder's resume
  command;
- :mod:`grt.runfolder.resume`: what ``resume=DIR`` may change, and the config the resumed work goes on with;
- :mod:`grt.runfolder.lock`: one process per folder, and a new run only in a new or empty folder.

The package imports none of them: each user imports the part it needs.
"""
