"""Loop-candidate search over stored keyframes and its precision/recall evaluation."""

from msa_slam.place_recognition.database import ExtraFrame, KeyframeDatabase, LoopMatch
from msa_slam.place_recognition.metrics import PRCurve, precision_recall

__all__ = ["ExtraFrame", "KeyframeDatabase", "LoopMatch", "PRCurve", "precision_recall"]
