"""Interactive rendering (Bikker 7.3.5 and 7.3.7): a converging image and a held frame rate.

**Converging.** Every frame renders fresh samples and is blended into the displayed image:
``C = C_prev (1 - f) + C_new f``. With a still camera and an unchanging scene, ``f = 1/n`` for
the n-th frame since the last reset, so the image is the exact running mean of all its frames
and converges without limit. Camera motion raises ``f``: a move of ``m`` (the view's shift as a
fraction of the field of view, see :func:`camera_motion`) gives ``f >= m / full_motion``, and a
move of ``full_motion`` or more starts over (``f = 1``). Scene commits change what is visible
without the camera knowing: after one, ``f`` stays at least ``min_blend`` until ``1/min_blend``
frames have passed, so moving objects leave no long ghosts (Bikker's floor), after which
convergence continues without the floor.

**Scaling the workload.** Frame time is nearly linear in samples per pixel (7.3.7), so after
every frame the spp for the next is ``spp * target / measured`` (smoothed, clamped to
``[1, max_spp]``). Below 1 spp the resolution drops in halves (down to 1/4 of each side);
above, it comes back first. A lower-resolution frame is upscaled (nearest) to the camera's size,
so the displayed image keeps its size; changing the resolution restarts convergence.

**Denoising** (:meth:`InteractiveSession.set_denoise`). With a quality other than ``off``, every
frame also renders the albedo and normal AOVs (where the integrator has them), blended into the
denoiser's guides by the same factor as the beauty, and :meth:`InteractiveSession.denoised`
denoises the converged blend, not each frame's fresh samples: as the blend converges, so does
what the denoiser sees, and the image stops flickering. The caller chooses where that runs (the
service: on its encoder thread, beside the next frame's rendering).
"""

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from cluster.coordinator import Coordinator
from cluster.frame import Frame
from cluster.scene_graph import SceneGraph
from tracer.integrators.aov import ALBEDO, NORMAL
from tracer.integrators.names import AOV_INTEGRATORS, DENOISE
from tracer.maths import portable
from tracer.post.denoise import Denoised
from tracer.post.guides import prefilter_argument, resolve_prefilter
from tracer.request import FrameRequest
from tracer.scene import format as fmt

RESOLUTION_SCALES = (1.0, 0.5, 0.25)
"""Fractions of the camera's width and height a session may render at, best first."""


def camera_motion(a: fmt.Camera, b: fmt.Camera) -> float:
    """How far the view moved from ``a`` to ``b``, in fields of view: the angle between the
    view directions plus the position change seen from the target distance, over the vertical
    field of view. 0 for the same view."""
    pa, pb = np.asarray(a.position, float), np.asarray(b.position, float)
    da, db = np.asarray(a.look_at, float) - pa, np.asarray(b.look_at, float) - pb
    turn = math.atan2(portable.norm(portable.cross(da, db)), portable.dot(da, db))
    shift = portable.norm(pb - pa) / max(portable.norm(da), 1e-300)
    zoom = abs(math.radians(b.vfov_deg) - math.radians(a.vfov_deg))
    size = (b.width, b.height) != (a.width, a.height)
    return math.inf if size else (turn + shift + zoom) / math.radians(a.vfov_deg)


class Convergence:
    """The blend factor of each frame (module docstring)."""

    def __init__(self, min_blend: float = 0.1, full_motion: float = 0.05):
        if not 0.0 < min_blend <= 1.0:
            raise ValueError("min_blend must be in (0, 1]")
        if not full_motion > 0.0:
            raise ValueError("full_motion must be positive")
        self.min_blend = min_blend
        self.full_motion = full_motion
        self.frames = 0
        """Frames blended since the last reset."""
        self.floor_frames = 0
        """Frames left during which ``min_blend`` bounds f from below (after a scene change)."""

    def reset(self) -> None:
        self.frames = 0

    def next_blend(self, motion: float = 0.0, scene_changed: bool = False) -> float:
        """The f for the next frame, given the camera's motion since the last frame."""
        if motion >= self.full_motion:
            self.frames = 0
        elif motion > 0.0:
            # Keep at most as much history as the motion allows: f >= motion / full_motion.
            self.frames = min(self.frames, max(0, math.floor(self.full_motion / motion) - 1))
        if scene_changed:
            self.floor_frames = math.ceil(1.0 / self.min_blend)
        self.frames += 1
        blend = 1.0 / self.frames
        if self.floor_frames > 0:
            self.floor_frames -= 1
            blend = max(blend, self.min_blend)
            self.frames = min(self.frames, math.ceil(1.0 / blend))
        return blend


class WorkloadScaler:
    """Samples per pixel and resolution that hold a target frame time (module docstring)."""

    def __init__(
        self, target_seconds: float, spp: int = 1, max_spp: int = 256, smoothing: float = 0.5
    ):
        if not target_seconds > 0.0:
            raise ValueError("the target frame time must be positive")
        self.target = target_seconds
        self.max_spp = max_spp
        self.smoothing = smoothing
        self.spp = max(1, min(spp, max_spp))
        self.scale_index = 0
        self._rate = float(self.spp)  # continuous spp the controller steers

    @property
    def scale(self) -> float:
        return RESOLUTION_SCALES[self.scale_index]

    def update(self, seconds: float) -> None:
        """Learn from a frame that took ``seconds`` at the current spp and scale."""
        if not seconds > 0.0:
            return
        wanted = self._rate * self.target / seconds
        self._rate = (1.0 - self.smoothing) * self._rate + self.smoothing * wanted
        if self._rate < 0.75 and self.scale_index < len(RESOLUTION_SCALES) - 1:
            self.scale_index += 1  # a quarter of the pixels: about 4x the samples per pixel
            self._rate *= 4.0
        elif self._rate > 6.0 and self.scale_index > 0:
            self.scale_index -= 1
            self._rate /= 4.0
        self._rate = min(max(self._rate, 1.0), float(self.max_spp))
        self.spp = max(1, min(self.max_spp, round(self._rate)))


@dataclass
class SessionFrame:
    index: int
    version: int
    image: np.ndarray
    """float32 (H, W, 3) linear radiance at the camera's full size: the converged image."""
    spp: int
    width: int
    height: int
    """The resolution this frame was rendered at (the image is upscaled to the camera's)."""
    blend: float
    seconds: float
    samples_accumulated: int
    """Effective samples per pixel behind the displayed image, ``spp / blend`` (exact for a
    running mean: n frames of spp samples)."""
    denoise: str = "off"
    """The quality the image is to be denoised at (``off``: shown as it is)."""
    guides: np.ndarray | None = None
    """float32 (H, W, 6): the blended albedo and normal behind ``image``, when denoising with
    guides (the integrator records AOVs)."""
    prefilter: bool | tuple[str, ...] = False
    """Which guides to prefilter (``tracer.post.denoise.denoise``'s ``prefilter``): the scene's
    ``render.denoise_prefilter``, ``auto`` resolved for it (``tracer.post.guides``)."""


class InteractiveSession:
    """A converging, rate-held view of a scene. ``render_next`` runs in the caller's thread
    (the one that owns the coordinator); ``set_camera`` and ``stats`` may be called from any."""

    def __init__(
        self,
        coordinator: Coordinator,
        graph: SceneGraph,
        target_fps: float = 10.0,
        min_blend: float = 0.1,
        max_spp: int = 256,
    ):
        if not target_fps > 0.0:
            raise ValueError("target_fps must be positive")
        self.coordinator = coordinator
        self.graph = graph
        self._lock = threading.Lock()
        self._camera = graph.state.camera
        self._rendered_camera: fmt.Camera | None = None
        self._version: int | None = None
        self._convergence = Convergence(min_blend)
        self._scaler = WorkloadScaler(1.0 / target_fps, max_spp=max_spp)
        self._image: np.ndarray | None = None
        self._guides: np.ndarray | None = None
        self._guide_frames = 0
        """Frames blended into the guides since they (re)started."""
        self._denoise = "off"
        self.last_frame: Frame | None = None
        """The coordinator's frame behind the latest session frame (tracers, idle, timings)."""
        self._index = 0
        self._fps = 0.0
        self._last: SessionFrame | None = None
        self.closed = False

    def set_camera(self, camera: fmt.Camera) -> None:
        """The view for the next frame; convergence restarts in proportion to the motion."""
        with self._lock:
            self._camera = camera

    @property
    def camera(self) -> fmt.Camera:
        with self._lock:
            return self._camera

    def set_denoise(self, quality: str) -> None:
        """Denoise the shown image from the next frame on at ``quality`` (``off``: do not)."""
        if quality not in DENOISE:
            raise ValueError(f"denoise must be one of {', '.join(DENOISE)}, not {quality!r}")
        with self._lock:
            self._denoise = quality

    @property
    def denoise(self) -> str:
        with self._lock:
            return self._denoise

    def render_next(self) -> SessionFrame:
        """Render one frame, blend it in and return the displayed image."""
        if self.closed:
            raise RuntimeError("the session is closed")
        camera = self.camera
        scale = self._scaler.scale
        spp = self._scaler.spp
        width = max(1, round(camera.width * scale))
        height = max(1, round(camera.height * scale))
        small = camera.model_copy(update={"width": width, "height": height})
        state = self.graph.state
        quality = self.denoise
        guided = quality != "off" and state.render.integrator in AOV_INTEGRATORS
        # The frame's own layers are never denoised: the blend is (``denoised``). Guides need
        # the single-ray kernel, which ``auto`` picks for them (the same image either way).
        changes = {"spp": spp, "aovs": guided, "denoise": "off"}
        if guided:
            changes["kernel"] = "auto"
        settings = state.render.model_copy(update=changes)
        motion = (
            0.0 if self._rendered_camera is None else camera_motion(self._rendered_camera, small)
        )
        start = time.perf_counter()
        frame = self.coordinator.render_frame(
            FrameRequest(frame=self._index, camera=small, settings=settings), graph=self.graph
        )
        seconds = time.perf_counter() - start
        self.last_frame = frame
        version = frame.version
        scene_changed = self._version is not None and version != self._version
        full = _upscale(frame.rgb, camera.height, camera.width)
        if self._image is None or motion == math.inf:
            self._convergence.reset()
        blend = self._convergence.next_blend(motion, scene_changed)
        restart = blend >= 1.0 or self._image is None
        self._image = _blended(self._image, full, blend, restart)
        if guided:
            aov = _upscale(frame.aov, camera.height, camera.width)
            albedo, normal = aov[..., ALBEDO : ALBEDO + 3], aov[..., NORMAL : NORMAL + 3]
            fresh = np.concatenate([albedo, normal], axis=2)
            restart = restart or self._guides is None
            self._guide_frames = 1 if restart else self._guide_frames + 1
            # Guides started after the image converged for a while are their own running mean
            # until they have as many frames as its blend.
            guide_blend = max(blend, 1.0 / self._guide_frames)
            self._guides = _blended(self._guides, fresh, guide_blend, restart)
        else:
            self._guides = None
        self._rendered_camera = small
        self._version = frame.version
        self._scaler.update(seconds)
        self._fps = 1.0 / seconds if self._fps == 0.0 else 0.8 * self._fps + 0.2 / seconds
        result = SessionFrame(
            index=self._index,
            version=frame.version,
            image=self._image.copy(),
            spp=spp,
            width=width,
            height=height,
            blend=blend,
            seconds=seconds,
            samples_accumulated=round(spp / blend),
            denoise=quality,
            guides=None if self._guides is None else self._guides.copy(),
            prefilter=guided and _prefilters(state, camera),
        )
        self._index += 1
        self._last = result
        return result

    @staticmethod
    def denoised(frame: SessionFrame, threads: int | None = None) -> Denoised | None:
        """``frame``'s image denoised at its quality (``tracer.post.denoise.Denoised``), guided
        by its blended guides where it has them; None when its quality is ``off``. Raises the
        denoiser's errors (``DenoiserUnavailable``, ``DenoiseFailed``)."""
        if frame.denoise == "off":
            return None
        from tracer.post.denoise import denoise

        albedo = normal = None
        if frame.guides is not None:
            albedo, normal = frame.guides[..., :3], frame.guides[..., 3:]
        return denoise(
            frame.image,
            albedo,
            normal,
            quality=frame.denoise,
            threads=threads,
            prefilter=frame.prefilter,
        )

    def stats(self) -> dict:
        """fps (smoothed), spp and resolution scale of the next frame, the last blend factor,
        frames rendered, the denoiser's quality."""
        last = self._last
        return {
            "fps": self._fps,
            "spp": self._scaler.spp,
            "scale": self._scaler.scale,
            "blend": None if last is None else last.blend,
            "frames": self._index,
            "samples_accumulated": 0 if last is None else last.samples_accumulated,
            "denoise": self.denoise,
        }

    def close(self) -> None:
        """Stop, and let go of every image buffer (the blended image, the last frame shown and
        the coordinator's frame behind it), even while something still holds the session."""
        self.closed = True
        self._image = None
        self._guides = None
        self._last = None
        self.last_frame = None


def _prefilters(state, camera: fmt.Camera) -> bool | tuple[str, ...]:
    """The guides the scene's ``render.denoise_prefilter`` (``auto`` resolved) prefilters."""
    settings = resolve_prefilter(state.render, state.materials.values(), camera)
    return prefilter_argument(settings.denoise_prefilter)


def _blended(
    shown: np.ndarray | None, fresh: np.ndarray, blend: float, restart: bool
) -> np.ndarray:
    """``shown (1 - blend) + fresh blend`` in place (a copy of ``fresh`` on ``restart``)."""
    if restart:
        return fresh.copy()
    shown *= np.float32(1.0 - blend)
    shown += np.float32(blend) * fresh
    return shown


def _upscale(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """Nearest-neighbour resize of ``image`` (h, w, channels) to (height, width, channels)."""
    h, w = image.shape[:2]
    if (h, w) == (height, width):
        return image
    rows = np.minimum((np.arange(height) * h) // height, h - 1)
    cols = np.minimum((np.arange(width) * w) // width, w - 1)
    return image[rows][:, cols]
