"""The pipeline (seed, start, solve, outliers, learnt noise), its result, and the report.

Exports (each imported from its module on first use): calibrate from calibrate.calibration.pipeline; Calibration,
NewMarker, Outlier from calibrate.calibration.result; MovedMarker, marker_places from calibrate.calibration.moved
(markers a static shows elsewhere on their segment); Identified, ParameterChange, Progress, StillNote, LimitNote
from calibrate.calibration.records; TruthComparison, compare_to_truth from calibrate.calibration.evaluate;
PipelineOptions (Settings.pipeline: the pipeline's switches) from calibrate.calibration.options; report_html,
write_report_html from calibrate.calibration.html (the HTML report); scene_of, view_scene from
calibrate.calibration.view (the 3-D view in rerun).
"""

from ..exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, """
.pipeline:calibrate .result:Calibration,NewMarker,Outlier .moved:MovedMarker,marker_places
.records:Identified,ParameterChange,Progress,StillNote,LimitNote .evaluate:TruthComparison,compare_to_truth
.options:PipelineOptions .html:report_html,write_report_html .view:scene_of,view_scene
""")
