"""Orchestration: the only layer that chains stages (extract, batch, demo, KITTI scenarios, evaluation runs).

Stages (``video``, ``perception``, ``geometry``, ``trajectory``, ``sim``, ``search``, ``export``, ``eval``,
``viz``) are libraries that take arrays and dataclasses; the pipelines here wire them together.
"""
