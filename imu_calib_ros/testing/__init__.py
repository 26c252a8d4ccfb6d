"""Test oracles that share no code with the estimator's own models.

``world_sim``: an independent bag generator written from CONTRACT sections 1-3 (the "world");
``world_units``: unit classes from navigation grade to consumer MEMS (raw errors, noise);
``world_cases``: small named cases in a temporary directory for tests (``make_case``).
"""
