"""Views of the console, one module per area; each view parses input, calls a service or a
selector and renders. Lookups by id always go through ``owned_*`` helpers (404 for others)."""
