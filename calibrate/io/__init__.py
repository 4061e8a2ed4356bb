"""Reading and writing: trials (C3D, TRC), motions (CSV), marker label maps, settings files, OpenSim models (import)
and exports (.osim, .mot, .trc)."""
