"""Server-side analysis of a model's logs (Django-free): sim-trace CSVs in, small chart data
out. :mod:`.trace` parses one iteration file and sums it up; :mod:`.summary` folds those sums
into one small object per run (stored, so a chart never parses the run's files again);
:mod:`.actions` says which action bin a step counts in (continuous spaces binned);
:mod:`.charts` turns a run's summary into what the browser draws; :mod:`.replay` rebuilds a
recorded episode's reward params."""
