"""OpenGL rendering of the world (moderngl + headless EGL); not part of the pure core.

* :class:`Renderer`: color, z-depth and instance ids of a camera pose in ``map``.
* :class:`RenderedFrame`, :class:`RenderSettings`.
"""

from uav_sim_bridge.render.gl_renderer import RenderedFrame, Renderer, RenderSettings

__all__ = ["RenderSettings", "RenderedFrame", "Renderer"]
