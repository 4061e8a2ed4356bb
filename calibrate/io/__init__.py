"""Reading and writing: trials (C3D, TRC), motions (CSV), marker label maps, settings files, OpenSim models (import)
and exports (.osim, .mot, .trc).

Exports (each from its module, imported on first use):

    Trial, strip_subject_prefix   -- calibrate.io.trial
    read_trial   -- calibrate.io.read
    read_c3d, write_c3d   -- calibrate.io.c3d
    read_trc, write_trc   -- calibrate.io.trc
    is_model_output, plugin_gait_centres   -- calibrate.io.vicon
    Motion, read_motion_csv, write_motion_csv   -- calibrate.io.motion
    LabelMapping, load_marker_map, map_labels   -- calibrate.io.labels
    load_settings, settings_from_dict   -- calibrate.io.config
    approximation_table, osim_info, with_locked   -- calibrate.io.osim_info
    export_osim, write_mot   -- calibrate.io.osim_export
"""

from ..exports import lazy_exports

_EXPORTS = {
    "Trial": ".trial",
    "strip_subject_prefix": ".trial",
    "read_trial": ".read",
    "read_c3d": ".c3d",
    "write_c3d": ".c3d",
    "read_trc": ".trc",
    "write_trc": ".trc",
    "is_model_output": ".vicon",
    "plugin_gait_centres": ".vicon",
    "Motion": ".motion",
    "read_motion_csv": ".motion",
    "write_motion_csv": ".motion",
    "LabelMapping": ".labels",
    "load_marker_map": ".labels",
    "map_labels": ".labels",
    "load_settings": ".config",
    "settings_from_dict": ".config",
    "approximation_table": ".osim_info",
    "osim_info": ".osim_info",
    "with_locked": ".osim_info",
    "export_osim": ".osim_export",
    "write_mot": ".osim_export",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
