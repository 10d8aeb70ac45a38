"""IDS industrial cameras (the paper's uEye) through IDS peak (``pip install inspect-pipe[ids]``
plus the IDS peak runtime); ``pyueye`` stands in on hosts with only the old uEye driver.

Vendor SDKs are imported when the source is opened, never at package import, and a missing
runtime or camera is an :class:`InputError` that says which and what to install. Software trigger:
each grab fires ``TriggerSoftware`` at the deadline, so frames are exactly on the schedule.
"""

from __future__ import annotations

import importlib

import numpy as np

from inspect_pipe.capture._clock import Clock
from inspect_pipe.capture._geometry import CameraModel
from inspect_pipe.capture._source import Grab, SourceInfo, SourceLost, default_cam_to_body
from inspect_pipe.errors import InputError

__all__ = ["IDSPeakSource", "UEyeSource", "ids_status", "open_ids"]

INSTALL_PEAK = "install the IDS peak runtime from ids-imaging.com, then: pip install 'inspect-pipe[ids]'"
INSTALL_UEYE = "install the IDS Software Suite (uEye driver) and: pip install pyueye"


def _import(name: str):
    try:
        return importlib.import_module(name), ""
    except Exception as err:  # ImportError, or OSError when the runtime library is missing
        return None, f"{name}: {err.__class__.__name__}: {err}".splitlines()[0]


def ids_status() -> tuple[bool, str]:
    """(usable, why) for the doctor: SDK importable and at least one camera attached."""
    mod, why = _import("ids_peak.ids_peak")
    if mod is None:
        umod, uwhy = _import("pyueye.ueye")
        if umod is None:
            return False, f"IDS peak not installed ({INSTALL_PEAK}); pyueye not installed either"
        return _ueye_count(umod)
    try:
        mod.Library.Initialize()
        dm = mod.DeviceManager.Instance()
        dm.Update()
        n = len(dm.Devices())
    except Exception as err:
        return False, f"IDS peak runtime not working: {err}"
    return (n > 0, f"{n} IDS camera(s) via IDS peak" if n else "IDS peak installed, no camera attached")


def _ueye_count(ueye) -> tuple[bool, str]:
    try:
        n = ueye.INT()
        if ueye.is_GetNumberOfCameras(n) != ueye.IS_SUCCESS:
            return False, "pyueye installed, uEye driver not running (start the ueyeusbdrc/ueyeethdrc daemon)"
        return (n.value > 0, f"{n.value} uEye camera(s) via pyueye" if n.value else "pyueye installed, no uEye camera attached")
    except Exception as err:
        return False, f"pyueye installed, uEye runtime missing ({err.__class__.__name__})"


def open_ids(*, clock: Clock, **kw):
    """The IDS peak source when its SDK imports, else the pyueye one, else an InputError."""
    if _import("ids_peak.ids_peak")[0] is not None:
        return IDSPeakSource(clock=clock, **kw)
    if _import("pyueye.ueye")[0] is not None:
        return UEyeSource(clock=clock, **kw)
    raise InputError("ids", "no IDS camera SDK found", INSTALL_PEAK)


class IDSPeakSource:
    def __init__(self, *, clock: Clock, serial: str | None = None, exposure_s: float = 0.004, fps: float = 10.0,
                 trigger: str = "software", hfov_deg: float = 60.0, timeout_s: float = 1.0) -> None:
        self.clock, self.serial, self.exposure_s, self.fps = clock, serial, exposure_s, fps
        self.trigger, self.hfov_deg, self.timeout_s = trigger, hfov_deg, timeout_s
        self._dev = self._ds = self._nm = None
        self._t0_dev_ns: int | None = None

    def open(self) -> SourceInfo:
        peak, why = _import("ids_peak.ids_peak")
        ext, why2 = _import("ids_peak.ids_peak_ipl_extension")
        ipl, why3 = _import("ids_peak_ipl.ids_peak_ipl")
        if peak is None or ext is None or ipl is None:
            raise InputError("ids", f"IDS peak SDK not usable ({why or why2 or why3})", INSTALL_PEAK)
        self._peak, self._ext, self._ipl = peak, ext, ipl
        peak.Library.Initialize()
        dm = peak.DeviceManager.Instance()
        dm.Update()
        descs = list(dm.Devices())
        if self.serial:
            descs = [d for d in descs if d.SerialNumber() == self.serial]
        if not descs:
            raise InputError(f"ids:{self.serial or ''}", "no IDS camera found", "check the cable and that IDS peak Cockpit sees the camera")
        desc = descs[0]
        self._dev = desc.OpenDevice(peak.DeviceAccessType_Control)
        nm = self._dev.RemoteDevice().NodeMaps()[0]
        self._nm = nm
        nm.FindNode("ExposureTime").SetValue(self.exposure_s * 1e6)
        if self.trigger == "software":
            nm.FindNode("TriggerSelector").SetCurrentEntry("ExposureStart")
            nm.FindNode("TriggerSource").SetCurrentEntry("Software")
            nm.FindNode("TriggerMode").SetCurrentEntry("On")
        elif self.trigger == "hardware":
            nm.FindNode("TriggerSelector").SetCurrentEntry("ExposureStart")
            nm.FindNode("TriggerSource").SetCurrentEntry("Line0")
            nm.FindNode("TriggerMode").SetCurrentEntry("On")
        else:
            nm.FindNode("TriggerMode").SetCurrentEntry("Off")
            nm.FindNode("AcquisitionFrameRate").SetValue(self.fps)
        self._ds = self._dev.DataStreams()[0].OpenDataStream()
        payload = nm.FindNode("PayloadSize").Value()
        for _ in range(max(3, self._ds.NumBuffersAnnouncedMinRequired())):
            self._ds.QueueBuffer(self._ds.AllocAndAnnounceBuffer(payload))
        nm.FindNode("TLParamsLocked").SetValue(1)
        self._ds.StartAcquisition()
        nm.FindNode("AcquisitionStart").Execute()
        w, h = int(nm.FindNode("Width").Value()), int(nm.FindNode("Height").Value())
        cam = CameraModel.from_hfov(w, h, self.hfov_deg, name=f"{desc.ModelName()} {desc.SerialNumber()}")
        return SourceInfo("ids", f"{desc.ModelName()} s/n {desc.SerialNumber()}", cam, default_cam_to_body(),
                          triggered=self.trigger == "software",
                          extra={"sdk": "ids_peak", "trigger": self.trigger, "exposure_s": self.exposure_s, "calibrated": False})

    def _underruns(self) -> int:
        try:
            nm = self._ds.NodeMaps()[0]
            return int(nm.FindNode("StreamLostFrameCount").Value()) + int(nm.FindNode("StreamIncompleteFrameCount").Value())
        except Exception:
            return 0

    def grab(self, deadline_s: float) -> Grab:
        peak = self._peak
        if self.trigger == "software":
            self.clock.sleep_until(deadline_s)
            t_trig = self.clock.now()
            self._nm.FindNode("TriggerSoftware").Execute()
        else:
            t_trig = None
        before = self._underruns()
        try:
            buf = self._ds.WaitForFinishedBuffer(int(self.timeout_s * 1000))
        except Exception as err:
            raise SourceLost(f"ids: no frame within {self.timeout_s} s ({err.__class__.__name__}; unplugged?)") from None
        t_host = self.clock.now()
        img = self._ext.BufferToImage(buf).ConvertTo(self._ipl.PixelFormatName_BGR8).get_numpy_3D().copy()
        frame_id, ts_ns = int(buf.FrameID()), int(buf.Timestamp_ns())
        self._ds.QueueBuffer(buf)
        exp = float(self._nm.FindNode("ExposureTime").Value()) * 1e-6
        start = t_trig if t_trig is not None else t_host - exp
        return Grab(image=np.ascontiguousarray(img), t_exposure_start_s=start, exposure_s=exp, t_host_s=t_host,
                    frame_id=frame_id, t_device_s=ts_ns * 1e-9, lost_before=max(0, self._underruns() - before))

    def close(self) -> None:
        try:
            if self._nm is not None:
                self._nm.FindNode("AcquisitionStop").Execute()
            if self._ds is not None:
                self._ds.StopAcquisition(self._peak.AcquisitionStopMode_Default)
                self._ds.Flush(self._peak.DataStreamFlushMode_DiscardAll)
                for b in self._ds.AnnouncedBuffers():
                    self._ds.RevokeBuffer(b)
            if self._nm is not None:
                self._nm.FindNode("TLParamsLocked").SetValue(0)
        except Exception:
            pass  # closing a camera that was unplugged
        finally:
            self._dev = self._ds = self._nm = None
            try:
                self._peak.Library.Close()
            except Exception:
                pass


class UEyeSource:
    """Old uEye driver through pyueye: software-triggered single frames (``is_FreezeVideo``)."""

    def __init__(self, *, clock: Clock, serial: str | None = None, exposure_s: float = 0.004, fps: float = 10.0,
                 trigger: str = "software", hfov_deg: float = 60.0, timeout_s: float = 1.0) -> None:
        self.clock, self.exposure_s, self.hfov_deg, self.timeout_s = clock, exposure_s, hfov_deg, timeout_s
        self._h = None
        self._n = 0

    def open(self) -> SourceInfo:
        ueye, why = _import("pyueye.ueye")
        if ueye is None:
            raise InputError("ids", f"pyueye not usable ({why})", INSTALL_UEYE)
        self._u = ueye
        h = ueye.HIDS(0)
        if ueye.is_InitCamera(h, None) != ueye.IS_SUCCESS:
            raise InputError("ids", "no uEye camera could be opened", "check the cable and that the uEye daemon runs")
        self._h = h
        ueye.is_SetColorMode(h, ueye.IS_CM_BGR8_PACKED)
        ueye.is_SetExternalTrigger(h, ueye.IS_SET_TRIGGER_SOFTWARE)
        ms = ueye.double(self.exposure_s * 1000)
        ueye.is_Exposure(h, ueye.IS_EXPOSURE_CMD_SET_EXPOSURE, ms, 8)
        rect = ueye.IS_RECT()
        ueye.is_AOI(h, ueye.IS_AOI_IMAGE_GET_AOI, rect, ueye.sizeof(rect))
        self._w, self._hh = int(rect.s32Width), int(rect.s32Height)
        self._mem, self._mid = ueye.c_mem_p(), ueye.int()
        ueye.is_AllocImageMem(h, self._w, self._hh, 24, self._mem, self._mid)
        ueye.is_SetImageMem(h, self._mem, self._mid)
        cam = CameraModel.from_hfov(self._w, self._hh, self.hfov_deg, name="uEye")
        return SourceInfo("ids", "uEye camera via pyueye", cam, default_cam_to_body(), triggered=True,
                          extra={"sdk": "pyueye", "exposure_s": self.exposure_s, "calibrated": False})

    def grab(self, deadline_s: float) -> Grab:
        u = self._u
        self.clock.sleep_until(deadline_s)
        t0 = self.clock.now()
        if u.is_FreezeVideo(self._h, int(self.timeout_s * 1000)) != u.IS_SUCCESS:
            raise SourceLost("ids: uEye capture failed (unplugged?)")
        t1 = self.clock.now()
        arr = u.get_data(self._mem, self._w, self._hh, 24, self._w * 3, copy=True)
        self._n += 1
        img = np.frombuffer(arr, np.uint8).reshape(self._hh, self._w, 3).copy()
        return Grab(image=img, t_exposure_start_s=t0, exposure_s=self.exposure_s, t_host_s=t1, frame_id=self._n)

    def close(self) -> None:
        if self._h is not None:
            try:
                self._u.is_FreeImageMem(self._h, self._mem, self._mid)
                self._u.is_ExitCamera(self._h)
            finally:
                self._h = None
