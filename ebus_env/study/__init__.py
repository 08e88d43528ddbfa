"""Fleet studies: charging infrastructure and ECO strategies by cost and grid load.

``load_study`` reads and checks a study file, ``run_study`` runs its scenarios (in-process or on
Ray) and streams one Parquet file per finished scenario, ``write_summary`` writes the tables,
plots and the HTML report.
"""

from ebus_env.study.rows import read_results
from ebus_env.study.study_file import StudySpec, load_study

__all__ = ["StudySpec", "load_study", "read_results", "run_study", "write_summary"]


def __getattr__(name):  # the runner and the report pull in numba and matplotlib: load on use
    if name == "run_study":
        from ebus_env.study.backends import run_study

        return run_study
    if name == "write_summary":
        from ebus_env.study.summary import write_summary

        return write_summary
    raise AttributeError(name)
