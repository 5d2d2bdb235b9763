"""The reconstruction folder's format: the name and version its ``metadata.json`` states and
the names of its files - written by :mod:`impress_gui.core.formats.writers`, read by
:mod:`impress_gui.core.measure.readings` and whatever checks a folder's files."""

from __future__ import annotations

RECON_FORMAT = "impress.reconstruction"
RECON_VERSION = 1

METADATA_FILE = "metadata.json"  # the parameters, inputs and every file's SHA-256
RUN_FILE = "run.json"  # timings and date: the one file that differs between identical runs
HEIGHTMAP_FILE = "heightmap.tif"  # the fused heightmap (float32 mm, NaN = no data)
X3P_FILE = "heightmap.x3p"
PLY_FILE = "pointcloud.ply"
TEXTURE_FILE = "texture.png"

#: the float32 maps (and the uint8 contribution codes), by layer name
LAYER_FILES = {
    "fused": HEIGHTMAP_FILE,
    "green": "height_green.tif",
    "red": "height_red.tif",
    "difference": "difference.tif",
    "contribution": "contribution.tif",
}
CONTRIBUTION_PNG = "contribution.png"
GREY8_PNG = "heightmap_8bit.png"
COLOUR_PNG = "heightmap_color.png"

#: every file of a reconstruction folder, in the order metadata.json lists their hashes
RECON_FILES = (*LAYER_FILES.values(), CONTRIBUTION_PNG, GREY8_PNG, COLOUR_PNG, PLY_FILE,
               X3P_FILE, TEXTURE_FILE, METADATA_FILE, RUN_FILE)
