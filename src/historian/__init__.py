"""The historian tier: records what the plant, PLC and supervisor publish, serves it back.

``store`` is its storage: one :class:`~historian.store.HistoryStore` interface, an embedded SQLite
back end (the default) and a PostgreSQL one (``TANKLAB_HISTORIAN_URL=postgresql://...``); see
docs/historian.md. The historian uses the kernel (:mod:`tanklab`) and :mod:`tanklab_io` only.
"""
