"""Moulds: the contract every source makes and every consumer reads (`mould`), and the
sources: the paper's random generator (`paper`) and a user's drawing (`read`, placed by
`place`; written back by `write`). `domain` says how far a mould lies from the generated
moulds a surrogate was trained on. A source imports from `mould` alone (docs/architecture.md)."""
