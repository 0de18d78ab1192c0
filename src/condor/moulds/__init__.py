"""Moulds: the contract every source makes and every consumer reads (`mould`), and the
sources: the paper's random generator (`paper`) and a user's drawing (`read`, with
`read_svg`, `read_dxf`, `shapes` and `units`; placed by `place`; written back by `write`).
`domain` says how far a mould lies from the generated moulds a surrogate was trained on. A
source imports the contract and never another source, so a new source (lab-style families, a
pure function of seed and id like the generator) is one more module here
(docs/architecture.md)."""
