"""Tuning a transferred mass-spring keyword spotter through its simulated network: the heads
refitted on the exact response (`refit`), then gradient epochs (`tune`). The last stage of
`kws`: it may import from every other subpackage."""
