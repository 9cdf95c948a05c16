"""Pictures, movies, notebook animations and a live window for flocking runs.

Importing this package imports matplotlib (``import flocking`` alone does not); files are
always drawn on matplotlib's Agg canvas, so no display is ever needed for them.

* :func:`plot_frame` draws a frame; :func:`animate` makes a movie file or a notebook video;
* :func:`write_movie`, :func:`write_picture`, :func:`write_plots` and :func:`after_run` are
  what the CLI uses; :mod:`.style` is the house style of every chart;
* :class:`LiveView` is a writer that shows a simulation while it runs.
"""

from .live import LiveView
from .movie import after_run, write_movie, write_picture, write_plots
from .notebook import animate, frame_png, trajectory_html, trajectory_mp4
from .scene import Scene, plot_frame

__all__ = ["LiveView", "Scene", "after_run", "animate", "frame_png", "plot_frame", "trajectory_html",
           "trajectory_mp4", "write_movie", "write_picture", "write_plots"]
