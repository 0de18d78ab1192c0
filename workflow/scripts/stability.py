"""Every stability case with every solver (condor.stability): one table."""
import logging

from condor.pipeline import setup_logging
from condor.stability import run_cases

setup_logging(snakemake.log[0])
df = run_cases(solvers=tuple(snakemake.params.solvers))
df.to_csv(snakemake.output[0], index=False)
logging.getLogger("condor").info("\n" + df.drop(columns=["what"]).to_string(index=False))
