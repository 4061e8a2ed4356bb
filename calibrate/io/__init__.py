"""Reading and writing: trials (C3D, TRC; read: QTM .tsv, Motive .csv), motions (CSV), marker label maps, settings
files, OpenSim models (import) and exports (.osim, .mot, .trc; MuJoCo's MJCF and qpos).

Exports (each imported from its module on first use): Trial, strip_subject_prefix from calibrate.io.trial;
read_trial from calibrate.io.read; read_c3d, write_c3d from calibrate.io.c3d; read_trc, write_trc from
calibrate.io.trc; read_qtm_tsv, read_motive_csv from calibrate.io.tables; is_model_output, plugin_gait_centres from
calibrate.io.vicon; Motion, read_motion_csv, write_motion_csv from calibrate.io.motion; LabelMapping,
load_marker_map, map_labels from calibrate.io.labels; load_settings, settings_from_dict from calibrate.io.config;
approximation_table, osim_info, with_locked from calibrate.io.osim_info; export_osim, write_mot from
calibrate.io.osim_export; export_mjcf, mjcf_qpos from calibrate.io.mjcf; ik_setup_locks, with_ik_setup,
ik_setup_range, scale_setup, ScaleSetup, TimeRange, apply_time_ranges, cut_to_setups, static_pose, setup_pose,
StaticPose from calibrate.io.osim_setup.
"""

from ..exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, """
.trial:Trial,strip_subject_prefix .read:read_trial .c3d:read_c3d,write_c3d .trc:read_trc,write_trc
.tables:read_qtm_tsv,read_motive_csv .vicon:is_model_output,plugin_gait_centres
.motion:Motion,read_motion_csv,write_motion_csv
.labels:LabelMapping,load_marker_map,map_labels .config:load_settings,settings_from_dict
.osim_info:approximation_table,osim_info,with_locked .osim_export:export_osim,write_mot .mjcf:export_mjcf,mjcf_qpos
.osim_setup:ik_setup_locks,with_ik_setup,ik_setup_range,scale_setup,ScaleSetup,TimeRange,apply_time_ranges,cut_to_setups
.osim_setup:static_pose,setup_pose,StaticPose
""")
