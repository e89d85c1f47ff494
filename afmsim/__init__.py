"""afmsim — a virtual atomic-force microscope.

The package mirrors the instrument's signal path:

``samples`` → ``tip`` → ``stage`` (hysteretic piezo plant) → ``scan`` → ``compensation``
→ ``metrics`` → ``diagnosis`` → ``render`` / ``report``.

SI units (metres, volts, seconds) everywhere inside the package; µm and nm appear only at the
edges (scenario YAML, plots, printed tables) and are always labelled there.
"""

__version__ = "0.1.0"
