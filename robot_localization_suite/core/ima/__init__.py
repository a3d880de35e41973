"""Camera topological localization with IMA (thesis 003, ``ima_topo_localizer``); see docs/ima.md."""
