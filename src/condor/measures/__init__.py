"""The measures: errors against the expected fields with the replica noise removed, and the paper's own metrics (docs/architecture.md)."""
