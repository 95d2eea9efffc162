"""Drake LeafSystems and diagram builders (imported as ``topodrake.systems``).

Each system is a thin wrapper over the batched functions in ``topodrake``;
no navigation math lives here.
"""
