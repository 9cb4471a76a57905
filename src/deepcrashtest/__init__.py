"""DeepCrashTest: dashcam crash video -> reproducible, parameterised virtual crash test."""

__version__ = "0.1.0"
