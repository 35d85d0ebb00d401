"""Time-domain parallel cloth simulation (Liang & Lin, SCA 2018) on Ray."""

from tryon.parallel.driver import ParallelOptions, run_scene_time_parallel, simulate_time_parallel

__all__ = ["ParallelOptions", "run_scene_time_parallel", "simulate_time_parallel"]
