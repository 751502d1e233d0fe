"""What a client uploads, checked before it reaches a session: images (size limit, a format whose
header gives the size, the pixel count read from the header before any pixel is decoded, a usable
name; stored under the suffix of the format their bytes are), and form fields holding JSON (read
as their schema, e.g. `Poses`), each error one line naming the field (`images[2]
(capture_000_02.png)`, `poses[1]`). Their pixels (decodable, RGB(A), the camera's size) are checked
by the session that adds them (`nerfaug.capture.images.check_image_files`).
"""

from __future__ import annotations

import io
import json
from pathlib import PurePath

from PIL import Image
from pydantic import ValidationError

from nerfaug.capture.images import ImageFile, check_file_name
from nerfaug.schema import adapter
from nerfaug.service.errors import ServiceError, bad_input, problems_line
from nerfaug.service.limits import MAX_CAPTURES_PER_REQUEST, MAX_IMAGE_PIXELS, MEGABYTE

# The formats an upload may be, by what Pillow reads in its header, and the suffixes that name them
# (the first is the one an upload is stored under when its name says another format).
UPLOAD_FORMATS = {
    "PNG": (".png",),
    "JPEG": (".jpg", ".jpeg"),
    "TIFF": (".tif", ".tiff"),
    "BMP": (".bmp",),
    "WEBP": (".webp",),
}


def read_upload(file, index: int, limit_bytes: int, max_pixels: int = MAX_IMAGE_PIXELS) -> ImageFile:
    """Read uploaded image `index` and check what bounds its cost: its name, bytes and header.

    Args:
        file: an object with `.filename` and a binary `.file` (FastAPI's `UploadFile`).
        index: its position in the request's `images` field.
        limit_bytes: the largest accepted file.
        max_pixels: the most pixels an image may have (checked in its header, before decoding).

    Raises:
        DatasetError: (a 422) a name that cannot name a view (`check_file_name`).
        ServiceError: 413 over the byte or pixel limit; 422 for a format other than `UPLOAD_FORMATS`.
    """
    filename = PurePath(str(file.filename or "")).name
    label = f"images[{index}] ({filename or 'no file name'})"
    stem, suffix = PurePath(filename).stem, PurePath(filename).suffix.lower()
    check_file_name(stem, suffix, label)  # before its bytes are read
    data = file.file.read(limit_bytes + 1)
    if len(data) > limit_bytes:
        raise ServiceError(413, f"{label}: larger than the upload limit of {limit_bytes / MEGABYTE:.3g} MB")
    kind, width, height = image_header(data, label)
    if width * height > max_pixels:
        raise ServiceError(
            413, f"{label}: {width}x{height} pixels is over the limit of {max_pixels} pixels per image (not decoded)"
        )
    if suffix not in UPLOAD_FORMATS[kind]:  # stored under the name its bytes say
        suffix = UPLOAD_FORMATS[kind][0]
    return ImageFile(stem, suffix, data)


def image_header(data: bytes, label: str) -> tuple[str, int, int]:
    """The format ("PNG", "JPEG", ...: a key of `UPLOAD_FORMATS`) and the size in pixels an image's
    header states, read without decoding its pixels; 422 naming `label` for anything else."""
    try:
        with Image.open(io.BytesIO(data)) as image:  # reads the header only
            kind, (width, height) = image.format, image.size
    except Image.DecompressionBombError:
        raise ServiceError(413, f"{label}: the image header states far too many pixels (not decoded)") from None
    except Exception:  # noqa: BLE001 -- Pillow raises many types; all mean "no header it knows"
        kind, width, height = None, 0, 0
    if kind not in UPLOAD_FORMATS:
        names = ", ".join(s for suffixes in UPLOAD_FORMATS.values() for s in suffixes)
        raise bad_input(f"{label}: not an image this service can read (send one of {names})")
    return kind, int(width), int(height)


def read_uploads(files: list, limit_bytes: int) -> list[ImageFile]:
    """Every uploaded image read and checked (`read_upload`); 413 for more than
    `MAX_CAPTURES_PER_REQUEST` (two of one name are refused where they are added:
    `nerfaug.capture.images.check_files`)."""
    if len(files) > MAX_CAPTURES_PER_REQUEST:
        raise ServiceError(
            413, f"images: {len(files)} files; a request may carry at most {MAX_CAPTURES_PER_REQUEST} images"
        )
    return [read_upload(f, i, limit_bytes) for i, f in enumerate(files)]


def form_json(text: str, field: str, kind):
    """A form field holding JSON, read as `kind` (a schema); 422 naming the field (`poses[1]`)
    when it is not JSON, or naming each refused field (`problems_line`) when it is not of that kind."""
    try:
        value = json.loads(text)
    except (json.JSONDecodeError, TypeError) as error:
        raise bad_input(f"{field}: not valid JSON ({getattr(error, 'msg', error)})") from None
    try:
        return adapter(kind).validate_python(value)
    except ValidationError as error:
        raise bad_input(problems_line(error.errors(), kind, field)) from None
