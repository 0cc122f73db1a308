"""The robot SDF: hash-grid encoder, unified model, baselines (NN-SDF, RDF), training and Table III evaluation.

    from samp.robot_sdf import load_robot_sdf
    sdf = load_robot_sdf("runs/robot_sdf_panda/<timestamp>")   # or its robot_sdf.pt / checkpoints/last.ckpt
    d = sdf.query(points, q)                                     # (B, N, 3), (B, n) -> (B, N) metres
"""

from samp.robot_sdf.artifact import load_robot_sdf, save_artifact
from samp.robot_sdf.baselines import NNSDF, BernsteinSDF, fit_bernstein
from samp.robot_sdf.encoding import HashGridEncoding
from samp.robot_sdf.evaluate import SDFEvalConfig, evaluate_methods
from samp.robot_sdf.model import UnifiedHashSDF
from samp.robot_sdf.samples import SampleConfig, SampleSet, ensure_samples, load_samples
from samp.robot_sdf.whole_robot import RobotSDF

__all__ = ["BernsteinSDF", "HashGridEncoding", "NNSDF", "RobotSDF", "SDFEvalConfig", "SampleConfig", "SampleSet",
           "UnifiedHashSDF", "ensure_samples", "evaluate_methods", "fit_bernstein", "load_robot_sdf", "load_samples",
           "save_artifact"]
