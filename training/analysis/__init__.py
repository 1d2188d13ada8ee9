"""Server-side analysis of a model's logs (Django-free): sim-trace CSVs in, small chart data
out. :mod:`.trace` parses one iteration file and sums it up once (callers cache the
:class:`~.trace.IterationSummary` per file); :mod:`.charts` combines the summaries into what
the browser draws."""
