"""Locating the board: thresholds and candidate dots (`segment`, `candidates`), the lattice search over
neighbours (`neighbours`, `lattice`, `labels`, `grid`, `recognise`), the search over scales and windows
(`search`) and the time budget it runs under (`budget`)."""
