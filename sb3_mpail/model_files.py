"""
MPAIL's model files: written whole or not at all, and refused with an error naming what is wrong before
Stable-Baselines3 reads them.
"""

import io
import json
import os
import pathlib
import zipfile
from typing import Any, Callable, Dict, Tuple, Union

import cloudpickle

#: settings every MPAIL model file holds (a file without them was saved by another algorithm)
MPAIL_SETTINGS = ("discriminator_learning_rate", "initial_temperature", "episodes_completed")


def save_atomically(path: Union[str, pathlib.Path], write: Callable[[io.BufferedIOBase], None]) -> None:
    """
    Writes a model file through ``write(file)`` beside its destination as ``<name>.partial``, then renames it over the
    destination, so a crash while saving never leaves a truncated checkpoint behind; a ``.partial`` left by a killed
    process is overwritten, and removed whatever happens. As Stable-Baselines3's ``save`` does, ``.zip`` is added to
    a name without a suffix, a symbolic link is followed (its target is written) and a read-only file is refused.

    :param path: the destination
    :param write: writes the model to an open binary file
    :raises PermissionError: the destination is a read-only file
    """
    destination = pathlib.Path(path)
    if destination.suffix == "":
        destination = destination.with_name(destination.name + ".zip")
    destination = destination.resolve()  # through symbolic links, to the file they name
    if destination.exists() and not destination.stat().st_mode & 0o222:  # by mode, as root too
        raise PermissionError(f"{destination} is read-only: MPAIL.save does not overwrite it (chmod u+w to allow).")
    destination.parent.mkdir(parents=True, exist_ok=True)
    partial = destination.with_name(destination.name + ".partial")
    try:
        with open(partial, "wb") as file:  # closed whatever happens (Stable-Baselines3 leaves its own open on errors)
            write(file)
        os.replace(partial, destination)
    finally:
        partial.unlink(missing_ok=True)


def raise_for_unpicklable_settings(policy_kwargs: Dict[str, Any], error: Exception) -> None:
    """
    After ``save`` failed with ``error``: refuses the first ``policy_kwargs`` setting cloudpickle cannot pickle (what
    Stable-Baselines3 saves them with), naming it; returns when they all pickle (``error`` has another cause).

    :raises TypeError: a setting cannot be pickled
    """
    for key, value in policy_kwargs.items():
        try:
            cloudpickle.dumps(value)
        except Exception as pickling_error:
            raise TypeError(
                f"policy_kwargs[{key!r}] (a {type(value).__name__}) cannot be saved: cloudpickle cannot pickle it "
                f"({pickling_error}). Give an object that holds no locks, threads or open files (or define its "
                "__getstate__); the file was not written."
            ) from error


def check_model_file(path: Union[str, pathlib.Path, io.BufferedIOBase]) -> Tuple[Any, Dict[str, Any]]:
    """
    Refuses what :meth:`MPAIL.load` cannot load, naming the file and what is wrong with it.

    :param path: the model file (``.zip`` may be left out, as Stable-Baselines3 allows) or a file object
    :return: what to load: the file (``path``, else ``<path>.zip``, also where ``path`` is a directory) or the file
        object, and the model's settings (its ``data`` member)
    :raises FileNotFoundError: there is no such file
    :raises ValueError: the file is empty, truncated, damaged, not a zip archive or a directory, its settings are not
        JSON, or it is not an MPAIL model
    """
    if isinstance(path, io.BufferedIOBase):
        name, source, start = getattr(path, "name", "<file object>"), path, path.tell()
    else:
        given = pathlib.Path(path)
        with_zip = given.with_name(given.name + ".zip")
        name = source = next((file for file in (given, with_zip) if file.is_file()), None)
        if source is None and given.is_dir():
            raise ValueError(f"MPAIL model file {given} is a directory, not a model file (and there is no {with_zip}).")
        if source is None:
            raise FileNotFoundError(f"MPAIL model file {given} does not exist (nor {with_zip}).")
        if source.stat().st_size == 0:
            raise ValueError(f"MPAIL model file {source} is empty (0 bytes): it was not saved whole.")
    try:
        with zipfile.ZipFile(source) as archive:
            members = archive.namelist()
            damaged = archive.testzip()
            settings = archive.read("data") if "data" in members and damaged is None else None
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as error:
        raise ValueError(f"MPAIL model file {name} is truncated or not a zip archive ({error}).") from error
    finally:
        if isinstance(path, io.BufferedIOBase):
            path.seek(start)
    if damaged is not None:
        raise ValueError(f"MPAIL model file {name} is damaged: its member {damaged} fails its CRC check (corrupted data).")
    try:
        data = None if settings is None else json.loads(settings)
    except ValueError as error:  # not JSON, or not text
        raise ValueError(
            f"MPAIL model file {name}: its 'data' member (the model's settings) is not JSON ({error}): the file was not "
            "written by MPAIL.save, or was changed since."
        ) from error
    if data is None or "policy.pth" not in members:
        raise ValueError(
            f"MPAIL model file {name} is truncated or not saved by Stable-Baselines3: it lacks the 'data' or 'policy.pth' "
            f"member (it holds {members})."
        )
    missing = [setting for setting in MPAIL_SETTINGS if setting not in data]
    if missing:
        policy_module = data.get("policy_class", {}).get("__module__", "an unknown module")
        raise ValueError(
            f"Model file {name} is not an MPAIL model: it lacks MPAIL's settings {missing}, and its policy class comes from "
            f"{policy_module}. Load it with the algorithm that saved it."
        )
    return source, data
