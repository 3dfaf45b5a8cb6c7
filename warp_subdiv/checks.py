"""Checks of values a user passes, shared by the vocabulary (mesh tags, options): numpy converts some values to
float64 without a word that are not numbers of a mesh or an option."""
import numpy as np

#: What numpy turns into a float that no sharpness or flatness is: True becomes 1, '2' becomes 2, the imaginary
#: part of a complex number is dropped.
NOT_NUMBERS = (bool, np.bool_, str, bytes, complex, np.complexfloating)


def first_non_number(values):
    """(index, item) of the first bool, string or complex number among ``values`` (a sequence or an array of any
    shape, read flat), or None where there is none or ``values`` is not array-like (its conversion to float64
    then says what is wrong)."""
    if isinstance(values, np.ndarray) and values.dtype.kind in "fiu":
        return None
    try:
        items = np.asarray(values, dtype=object).ravel().tolist()
    except (TypeError, ValueError):
        return None
    if not any(issubclass(kind, NOT_NUMBERS) for kind in set(map(type, items))):  # the types present, not a loop
        return None
    return next((i, x) for i, x in enumerate(items) if isinstance(x, NOT_NUMBERS))


__all__ = ["NOT_NUMBERS", "first_non_number"]
