#!/usr/bin/env python3
"""The peer benchmark: VTK's GPU ray-cast mapper against mixvol, same volume, camera, transfer
function, step and image size, interleaved in one run (issue 17).

Run it through scripts/peer-bench.sh, which installs VTK (the PyPI wheel, headless through EGL on
the same Mesa driver mixvol's lavapipe runs on), builds mixvol and fetches the MNI152 template.

Scenes: Marschner-Lobb 128^3 f32 (the `fire` transfer function) and the MNI152 2009a T1
template 197x233x189 u8 (`mri`), each unshaded and with Blinn-Phong shading. Both renderers read
the same raw voxels (written here), centred at the origin with the longest side 1, seen from the
same eye, target, up vector and vertical field of view, with a 0.5-voxel step, opacity per voxel
length, linear interpolation, composite blending and the same background.

Configurations, run in this order in every round (rounds interleave them, so a change in the
machine's load touches all alike):
  vtk            vtkGPUVolumeRayCastMapper (vtkOpenGLGPUVolumeRayCastMapper), full resolution
  plain          mixvol's single-texture ray-caster
  cache-all-hi   mixvol's brick cache with every brick hi-res
  half-smooth    half the bricks low-res, smooth (C0) transitions
  half-disc      the same residency, discontinuous transitions (the baseline)

Each configuration renders one warm-up frame and then --frames timed frames per round; a round's
figure is the median of its frames, the reported figure the median over --rounds rounds. For VTK
a frame is Render() followed by WaitForCompletion(); for mixvol it is the CLI's per-frame CPU time
(record, submit, wait on the fence). Both are wall-clock times on whatever device runs them: on
lavapipe / llvmpipe they are CPU times and only the ratios in one run mean something.

Output (under --out, default out/peer): peer-bench.md and peer-bench.json (the table), and per
scene and shading the VTK image, mixvol's plain image and both side by side (*-pair.png), with
the mean absolute RGB difference of the two printed in the table (the renderers differ in small
ways: VTK's bounds end at the outer voxel centres, its lighting model and opacity correction are
its own; the pair is for the eye).
"""

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
import vtk  # noqa: E402
from vtk.util import numpy_support  # noqa: E402
from PIL import Image  # noqa: E402

# mixvol's transfer-function presets (src/optics/mod.rs, TransferFunction::preset): control
# points (position in [0, 1], r, g, b, opacity per voxel length).
TF_PRESETS = {
    "fire": [
        (0.0, 0.0, 0.0, 0.0, 0.0),
        (0.40, 0.5, 0.05, 0.0, 0.0),
        (0.46, 0.9, 0.3, 0.05, 0.08),
        (0.50, 1.0, 0.85, 0.4, 0.6),
        (0.54, 0.9, 0.3, 0.05, 0.08),
        (0.60, 0.5, 0.05, 0.0, 0.0),
        (1.0, 0.0, 0.0, 0.0, 0.0),
    ],
    "mri": [
        (0.0, 0.0, 0.0, 0.0, 0.0),
        (0.12, 0.0, 0.0, 0.0, 0.0),
        (0.35, 0.6, 0.5, 0.45, 0.04),
        (0.7, 0.95, 0.9, 0.85, 0.25),
        (1.0, 1.0, 1.0, 1.0, 0.5),
    ],
}

# mixvol's defaults (crates/mixvol-cli/src/args.rs, src/scene.rs Shading::default).
EYE = (1.0, 1.3, 1.4)
TARGET = (0.0, 0.0, 0.0)
UP = (0.0, 1.0, 0.0)
FOV_DEG = 35.0
BACKGROUND = (0.08, 0.08, 0.1)
AMBIENT, DIFFUSE, SPECULAR, SHININESS = 0.3, 0.7, 0.3, 24.0
SAMPLES_PER_VOXEL = 2  # a 0.5-voxel step

CONFIGS = ["vtk", "plain", "cache-all-hi", "half-smooth", "half-disc"]
MIXVOL_FLAGS = {
    "plain": [],
    "cache-all-hi": ["--levels", "all-hi"],
    "half-smooth": ["--levels", "half", "--transition", "smooth"],
    "half-disc": ["--levels", "half", "--transition", "discontinuous"],
}


def marschner_lobb(n):
    """Marschner-Lobb (fM = 6, alpha = 0.25) at voxel centres of an n^3 grid over [-1, 1]^3, as
    src/volume/synthetic.rs samples it; array axes (z, y, x)."""
    c = -1.0 + 2.0 * (np.arange(n, dtype=np.float64) + 0.5) / n
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    r = np.sqrt(x * x + y * y)
    rho_r = np.cos(2.0 * np.pi * 6.0 * np.cos(np.pi * r / 2.0))
    v = (1.0 - np.sin(np.pi * z / 2.0) + 0.25 * (1.0 + rho_r)) / (2.0 * 1.25)
    return v.astype(np.float32)


def read_nifti_u8(path):
    """The voxels of a NIfTI-1 file holding u8 data (datatype 2), array axes (z, y, x)."""
    raw = path.read_bytes()
    for endian in ("<", ">"):
        if np.frombuffer(raw[:4], dtype=endian + "i4")[0] == 348:
            break
    else:
        raise SystemExit(f"{path}: not a NIfTI-1 file (sizeof_hdr is not 348)")
    dim = np.frombuffer(raw[40:56], dtype=endian + "i2")
    datatype = int(np.frombuffer(raw[70:72], dtype=endian + "i2")[0])
    vox_offset = int(np.frombuffer(raw[108:112], dtype=endian + "f4")[0])
    if datatype != 2:
        raise SystemExit(f"{path}: datatype {datatype}, expected 2 (u8)")
    nx, ny, nz = int(dim[1]), int(dim[2]), int(dim[3])
    data = np.frombuffer(raw, dtype=np.uint8, count=nx * ny * nz, offset=vox_offset)
    return data.reshape(nz, ny, nx)


class VtkScene:
    """One VTK render window with the volume, camera, transfer function and shading of a scene."""

    def __init__(self, data, tf_name, shaded, size):
        nz, ny, nx = data.shape
        s = 1.0 / max(nx, ny, nz)
        image = vtk.vtkImageData()
        image.SetDimensions(nx, ny, nz)
        image.SetSpacing(s, s, s)
        # Voxel centres where mixvol puts them: the box [-n s / 2, n s / 2] per axis.
        image.SetOrigin(-nx * s / 2 + s / 2, -ny * s / 2 + s / 2, -nz * s / 2 + s / 2)
        array = numpy_support.numpy_to_vtk(data.ravel(), deep=True)
        image.GetPointData().SetScalars(array)

        scale = 255.0 if data.dtype == np.uint8 else 1.0
        colour = vtk.vtkColorTransferFunction()
        opacity = vtk.vtkPiecewiseFunction()
        for pos, r, g, b, a in TF_PRESETS[tf_name]:
            colour.AddRGBPoint(pos * scale, r, g, b)
            opacity.AddPoint(pos * scale, a)

        prop = vtk.vtkVolumeProperty()
        prop.SetColor(colour)
        prop.SetScalarOpacity(opacity)
        prop.SetScalarOpacityUnitDistance(s)  # mixvol: opacity per voxel length
        prop.SetInterpolationTypeToLinear()
        if shaded:
            prop.ShadeOn()
            prop.SetAmbient(AMBIENT)
            prop.SetDiffuse(DIFFUSE)
            prop.SetSpecular(SPECULAR)
            prop.SetSpecularPower(SHININESS)
        else:
            prop.ShadeOff()

        mapper = vtk.vtkGPUVolumeRayCastMapper()
        mapper.SetInputData(image)
        mapper.SetBlendModeToComposite()
        mapper.SetAutoAdjustSampleDistances(0)
        mapper.SetSampleDistance(s / SAMPLES_PER_VOXEL)

        volume = vtk.vtkVolume()
        volume.SetMapper(mapper)
        volume.SetProperty(prop)

        renderer = vtk.vtkRenderer()
        renderer.AddVolume(volume)
        renderer.SetBackground(*BACKGROUND)
        camera = renderer.GetActiveCamera()
        camera.SetPosition(*EYE)
        camera.SetFocalPoint(*TARGET)
        camera.SetViewUp(*UP)
        camera.SetViewAngle(FOV_DEG)
        renderer.ResetCameraClippingRange()
        # A headlight, as mixvol lights along the ray.
        renderer.RemoveAllLights()
        light = vtk.vtkLight()
        light.SetLightTypeToHeadlight()
        renderer.AddLight(light)

        self.window = vtk.vtkRenderWindow()
        self.window.SetOffScreenRendering(1)
        self.window.SetSize(size, size)
        self.window.AddRenderer(renderer)
        self.device = "?"

    def frame_ms(self):
        t0 = time.perf_counter()
        self.window.Render()
        self.window.WaitForCompletion()
        return (time.perf_counter() - t0) * 1e3

    def run(self, frames):
        self.frame_ms()  # warm-up: shader compilation and uploads
        caps = self.window.ReportCapabilities().splitlines()
        self.device = next((l.split(":", 1)[1].strip() for l in caps if "renderer string" in l), "?")
        return [self.frame_ms() for _ in range(frames)]

    def image(self):
        grab = vtk.vtkWindowToImageFilter()
        grab.SetInput(self.window)
        grab.SetInputBufferTypeToRGB()
        grab.ReadFrontBufferOff()
        grab.Update()
        out = grab.GetOutput()
        w, h, _ = out.GetDimensions()
        rgb = numpy_support.vtk_to_numpy(out.GetPointData().GetScalars()).reshape(h, w, 3)
        return rgb[::-1].copy()  # VTK's rows run bottom-up


CPU_LINE = re.compile(r"cpu min ([\d.]+) / median ([\d.]+) / max ([\d.]+) ms")
RAYCAST_LINE = re.compile(r"gpu ray-cast pass: min ([\d.]+) / median ([\d.]+)")
DEVICE_LINE = re.compile(r"^device: (.*)$", re.M)


def mixvol_run(binary, raw, dims, scalar, tf_name, shaded, size, frames, flags, output):
    cmd = [
        str(binary), "render",
        "--volume", str(raw),
        "--dims", ",".join(str(d) for d in dims),
        "--scalar", scalar,
        "--tf", tf_name,
        "--window", "0,1",
        "--samples-per-voxel", str(SAMPLES_PER_VOXEL),
        "--width", str(size), "--height", str(size),
        "--frames", str(frames),
        "-o", str(output),
    ] + (["--shading"] if shaded else []) + flags
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"mixvol failed ({' '.join(cmd)}):\n{done.stderr}{done.stdout}")
    cpu = CPU_LINE.search(done.stdout)
    if not cpu:
        raise SystemExit(f"no frame timing in mixvol's output:\n{done.stdout}")
    raycast = RAYCAST_LINE.search(done.stdout)
    device = DEVICE_LINE.search(done.stdout)
    return {
        "median_ms": float(cpu.group(2)),
        "raycast_median_ms": float(raycast.group(2)) if raycast else None,
        "device": device.group(1) if device else "?",
    }


def write_atomic(path, text):
    """Writes `text` to a temporary file beside `path`, syncs it and renames it over `path`."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def save_png_atomic(path, image):
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".png")
    os.close(fd)
    try:
        image.save(tmp, format="PNG")
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mixvol", required=True, help="path of the mixvol binary")
    ap.add_argument("--mni", required=True, help="path of mni_icbm152_t1_tal_nlin_sym_09a_converted.nii")
    ap.add_argument("--out", default="out/peer", help="output folder")
    ap.add_argument("--size", type=int, default=512, help="image width and height in pixels")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=7, help="timed frames per configuration and round")
    ap.add_argument("--scenes", default="ml,mni", help="comma-separated: ml, mni")
    ap.add_argument("--shading", default="off,on", help="comma-separated: off, on")
    args = ap.parse_args()
    for name, value in (("--size", args.size), ("--rounds", args.rounds), ("--frames", args.frames)):
        if value < 1:
            raise SystemExit(f"{name} must be at least 1, got {value}")

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    binary = Path(args.mixvol)
    scenes = {}
    for name in args.scenes.split(","):
        if name == "ml":
            scenes["Marschner-Lobb 128^3 f32"] = ("ml", marschner_lobb(128), "f32", "fire")
        elif name == "mni":
            scenes["MNI152 T1 197x233x189 u8"] = ("mni", read_nifti_u8(Path(args.mni)), "u8", "mri")
        else:
            raise SystemExit(f"--scenes: unknown scene '{name}' (expected ml or mni)")
    shadings = []
    for s in args.shading.split(","):
        if s not in ("off", "on"):
            raise SystemExit(f"--shading: '{s}' is neither off nor on")
        shadings.append(s == "on")

    rows = []
    devices = {}
    for title, (tag, data, scalar, tf_name) in scenes.items():
        raw = out / f"{tag}.raw"
        voxels = data.tobytes()
        if not raw.exists() or raw.read_bytes() != voxels:
            tmp = raw.with_suffix(".raw.tmp")
            tmp.write_bytes(voxels)
            os.replace(tmp, raw)
        dims = (data.shape[2], data.shape[1], data.shape[0])
        for shaded in shadings:
            label = f"{tag}-{'shaded' if shaded else 'unshaded'}"
            vtk_scene = VtkScene(data, tf_name, shaded, args.size)
            per_round = {c: [] for c in CONFIGS}
            raycast = {c: [] for c in CONFIGS}
            for r in range(args.rounds):
                for config in CONFIGS:
                    if config == "vtk":
                        per_round[config].append(statistics.median(vtk_scene.run(args.frames)))
                        devices["vtk"] = vtk_scene.device
                    else:
                        res = mixvol_run(binary, raw, dims, scalar, tf_name, shaded, args.size,
                                         args.frames, MIXVOL_FLAGS[config],
                                         out / f"{label}-{config}.png")
                        devices["mixvol"] = res["device"]
                        per_round[config].append(res["median_ms"])
                        if res["raycast_median_ms"] is not None:
                            raycast[config].append(res["raycast_median_ms"])
                print(f"{label} round {r + 1}/{args.rounds}: " + ", ".join(
                    f"{c} {per_round[c][-1]:.1f} ms" for c in CONFIGS), flush=True)
            medians = {c: statistics.median(v) for c, v in per_round.items()}
            vtk_rgb = vtk_scene.image()
            save_png_atomic(out / f"{label}-vtk.png", Image.fromarray(vtk_rgb))
            mix_rgb = np.asarray(Image.open(out / f"{label}-plain.png").convert("RGB"))
            pair = np.concatenate([vtk_rgb, mix_rgb], axis=1)
            save_png_atomic(out / f"{label}-pair.png", Image.fromarray(pair))
            diff = float(np.abs(vtk_rgb.astype(np.int32) - mix_rgb.astype(np.int32)).mean())
            rows.append({
                "scene": title,
                "shaded": shaded,
                "median_ms": medians,
                "raycast_median_ms": {c: statistics.median(v) for c, v in raycast.items() if v},
                "rounds_ms": per_round,
                "mean_abs_rgb_difference_vtk_vs_plain": diff,
            })
            del vtk_scene

    md = [
        "# Peer benchmark: VTK's GPU ray-cast mapper against mixvol",
        "",
        f"Date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {args.size}x{args.size}, "
        f"0.5-voxel step, medians of {args.rounds} interleaved rounds of {args.frames} frames; "
        f"load average at the end {os.getloadavg()[0]:.1f}.",
        f"VTK {vtk.vtkVersion.GetVTKVersion()}: {devices.get('vtk', '?')}; mixvol: "
        f"{devices.get('mixvol', '?')}.",
        "Frame times in ms; the ratios in brackets are against VTK.",
        "",
        "| scene | shading | VTK | plain texture | cache, all hi-res | half hi-res, smooth "
        "| half hi-res, discontinuous | all-hi / plain | smooth / disc | RGB diff VTK vs plain |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        m = row["median_ms"]
        v = m["vtk"]
        cells = [f"{m[c]:.0f} ({m[c] / v:.2f}x)" for c in CONFIGS[1:]]
        md.append(
            f"| {row['scene']} | {'on' if row['shaded'] else 'off'} | {v:.0f} | "
            + " | ".join(cells)
            + f" | {m['cache-all-hi'] / m['plain']:.2f}x | {m['half-smooth'] / m['half-disc']:.2f}x"
            + f" | {row['mean_abs_rgb_difference_vtk_vs_plain']:.1f} |"
        )
    md.append("")
    md.append("Targets (issue 17): all-hi / plain <= 1.3x; smooth / discontinuous <= 1.15x; "
              "half smooth shaded <= 0.5x of VTK shaded; plain <= 0.5x of VTK.")
    text = "\n".join(md) + "\n"
    print(text)
    write_atomic(out / "peer-bench.md", text)
    write_atomic(out / "peer-bench.json", json.dumps({
        "size": args.size, "rounds": args.rounds, "frames": args.frames,
        "devices": devices, "vtk_version": vtk.vtkVersion.GetVTKVersion(), "rows": rows,
    }, indent=2) + "\n")
    print(f"wrote {out / 'peer-bench.md'}, {out / 'peer-bench.json'} and the image pairs in {out}")


if __name__ == "__main__":
    sys.exit(main())
