"""ScanNet++ semantic labels → ADE20K classes: the table the benchmark ships.

The rows are ScanNet++'s public 100-class semantic benchmark list (``top100`` of the ScanNet++
toolkit, in its order), each mapped by hand to the nearest ADE20K-150 class by meaning: the
class the perception model would predict for that surface. Raw annotation labels outside the
list are matched through the simulator's name/synonym table (``scannetpp.ade20k_label``).
"""

from __future__ import annotations

from riskfield.protocol import ade20k

#: ScanNet++ label → ADE20K class name.
SCANNETPP_TO_ADE20K: dict[str, str] = {
    "wall": "wall", "ceiling": "ceiling", "floor": "floor", "table": "table", "door": "door",
    "ceiling lamp": "light", "cabinet": "cabinet", "blinds": "blind", "curtain": "curtain", "chair": "chair",
    "storage cabinet": "cabinet", "office chair": "swivel chair", "bookshelf": "bookcase",
    "whiteboard": "bulletin board", "window": "windowpane", "box": "box", "window frame": "windowpane",
    "monitor": "monitor", "shelf": "shelf", "doorframe": "door", "pipe": "pole", "heater": "radiator",
    "kitchen cabinet": "cabinet", "sofa": "sofa", "windowsill": "windowpane", "bed": "bed",
    "shower wall": "wall", "trash can": "ashcan", "book": "book", "plant": "plant", "blanket": "blanket",
    "tv": "television receiver", "computer tower": "computer", "kitchen counter": "counter",
    "refrigerator": "refrigerator", "jacket": "apparel", "electrical duct": "wall", "sink": "sink",
    "bag": "bag", "picture": "painting", "pillow": "pillow", "towel": "towel", "suitcase": "bag",
    "backpack": "bag", "crate": "box", "keyboard": "computer", "rack": "shelf", "toilet": "toilet",
    "paper": "book", "printer": "computer", "poster": "poster", "painting": "painting",
    "microwave": "microwave", "board": "bulletin board", "shoes": "apparel", "socket": "wall",
    "bottle": "bottle", "bucket": "pot", "cushion": "cushion", "basket": "basket", "shoe rack": "shelf",
    "telephone": "box", "file folder": "book", "cloth": "apparel", "blind rail": "blind",
    "laptop": "computer", "plant pot": "pot", "exhaust fan": "fan", "cup": "glass", "coat hanger": "apparel",
    "light switch": "wall", "speaker": "box", "table lamp": "lamp", "air vent": "wall",
    "clothes hanger": "apparel", "kettle": "pot", "smoke detector": "ceiling", "container": "box",
    "power strip": "box", "slippers": "apparel", "paper bag": "bag", "mouse": "computer",
    "cutting board": "tray", "toilet paper": "towel", "paper towel": "towel", "pot": "pot", "clock": "clock",
    "pan": "pot", "tap": "sink", "jar": "vase", "soap dispenser": "bottle", "binder": "book", "bowl": "plate",
    "tissue box": "box", "whiteboard eraser": "box", "toilet brush": "box", "spray bottle": "bottle",
    "headphones": "box", "stapler": "box", "marker": "box",
}


def scannetpp_to_ade20k(label: str) -> int | None:
    """ADE20K index of a ScanNet++ benchmark label (case and spacing ignored); ``None`` when the
    label is not in the table."""
    name = SCANNETPP_TO_ADE20K.get(" ".join(str(label).lower().replace("_", " ").split()))
    return None if name is None else ade20k.index(name)
