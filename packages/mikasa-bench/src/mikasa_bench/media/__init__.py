"""Pixels: where workers render, episode videos and the task gallery.

* `mikasa_bench.media.render`: the render device of a worker (ManiSkill's render backend,
  lavapipe-only Vulkan for CPU rendering) and the check of where it really renders;
* `mikasa_bench.media.video`: the composed frame (scene view beside the two cameras) and
  the streamed mp4 encoder of ``--video``;
* `mikasa_bench.media.gallery` and `mikasa_bench.media.gallery_html`: ``mikasa-bench
  gallery``, an animated oracle episode per task and the HTML page showing them.

Import names from those modules; this package file imports nothing.
"""
