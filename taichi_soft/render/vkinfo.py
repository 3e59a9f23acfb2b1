"""Which Vulkan devices this machine has, asked of the Vulkan loader directly (ctypes, no Taichi).

``--renderer auto`` uses it: GGUI on a GPU, the Taichi rasterizer where the only Vulkan device
is a CPU (Mesa's lavapipe) or there is none. Creating a bare instance and listing devices takes
a few ms and opens no window.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools

# VkPhysicalDeviceType
DEVICE_TYPES = {0: "other", 1: "integrated-gpu", 2: "discrete-gpu", 3: "virtual-gpu", 4: "cpu"}
_VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO = 1


class _InstanceCreateInfo(ctypes.Structure):
    _fields_ = [("sType", ctypes.c_int), ("pNext", ctypes.c_void_p), ("flags", ctypes.c_uint32),
                ("pApplicationInfo", ctypes.c_void_p), ("enabledLayerCount", ctypes.c_uint32),
                ("ppEnabledLayerNames", ctypes.c_void_p), ("enabledExtensionCount", ctypes.c_uint32),
                ("ppEnabledExtensionNames", ctypes.c_void_p)]


@functools.lru_cache(maxsize=1)
def vulkan_devices() -> tuple[tuple[str, str], ...] | None:
    """(name, type) of every Vulkan physical device, type one of ``DEVICE_TYPES``' values;
    ``()`` when the loader finds no driver, ``None`` when there is no Vulkan loader at all."""
    path = ctypes.util.find_library("vulkan") or "libvulkan.so.1"
    try:
        vk = ctypes.CDLL(path)
    except OSError:
        return None
    info = _InstanceCreateInfo(sType=_VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO)
    instance = ctypes.c_void_p()
    if vk.vkCreateInstance(ctypes.byref(info), None, ctypes.byref(instance)) != 0:
        return ()
    try:
        count = ctypes.c_uint32(0)
        vk.vkEnumeratePhysicalDevices(instance, ctypes.byref(count), None)
        handles = (ctypes.c_void_p * count.value)()
        if count.value and vk.vkEnumeratePhysicalDevices(instance, ctypes.byref(count), handles) not in (0, 5):
            return ()
        devices = []
        for h in handles[:count.value]:
            # VkPhysicalDeviceProperties: apiVersion, driverVersion, vendorID, deviceID (u32 each),
            # deviceType (i32, offset 16), deviceName (char[256], offset 20), ... (< 1 KiB in all).
            props = ctypes.create_string_buffer(4096)
            vk.vkGetPhysicalDeviceProperties(ctypes.c_void_p(h), props)
            kind = int.from_bytes(props.raw[16:20], "little")
            name = props.raw[20:276].split(b"\0", 1)[0].decode(errors="replace")
            devices.append((name, DEVICE_TYPES.get(kind, "other")))
        return tuple(devices)
    finally:
        vk.vkDestroyInstance(instance, None)


def has_gpu_vulkan() -> bool:
    """True when Vulkan offers a GPU (integrated, discrete or virtual), where GGUI draws fast."""
    return any(kind.endswith("gpu") for _, kind in vulkan_devices() or ())
