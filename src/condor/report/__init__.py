"""The run's report: the HTML kit (`kit`), the verdict rules (`verdicts`), the workflow's
report page (`page.condor_report`) and its check in headless Chromium (`screenshot`)."""
