# The report (filled in by the report stage).
