"""Shared fixtures.  The synthetic-scene fixtures are added with `demtool synth`."""
