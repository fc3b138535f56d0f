"""Config: typed configuration, the bottom layer of user input.

* :mod:`.schema` — the sections as dataclasses; each field's constraint and hash rule live in its metadata.
* :mod:`.parsing` — what a user writes besides YAML: UTC times, TLE lines, mesh files.
* :mod:`.validate` — a mapping validated into a :class:`~.schema.Config`, every error naming its key.
* :mod:`.hashing` — the config as a dict, and the hashes every cache and store keys on.
* :mod:`.devices` — whether the named device exists here, and its free memory.
* :mod:`.load` — YAML, ``--set`` overrides, and the layer's names re-exported.
"""
