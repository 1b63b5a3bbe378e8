"""Type stubs of the stablesurf extension module (see docs/python.md); maturin ships this file,
found beside pyproject.toml, as the package's __init__.pyi with py.typed."""

from os import PathLike
from typing import Any, Literal, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

__version__: str

ArrayLike = npt.ArrayLike

class Scan:
    """A scan read by the tool's own importer."""

    @property
    def points(self) -> npt.NDArray[np.float64]: ...
    @property
    def normals(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def faces(self) -> Optional[npt.NDArray[np.uint32]]: ...
    @property
    def colours(self) -> Optional[npt.NDArray[np.uint16]]: ...
    @property
    def notices(self) -> list[str]: ...
    def __len__(self) -> int: ...

class Polynomial:
    """An implicit polynomial f; f < 0 inside, f > 0 outside."""

    @property
    def degree(self) -> int: ...
    @property
    def coefficients(self) -> npt.NDArray[np.float64]: ...
    @property
    def center(self) -> npt.NDArray[np.float64]: ...
    @property
    def scale(self) -> float: ...
    @property
    def kappa(self) -> Optional[float]: ...
    @property
    def bounded(self) -> Optional[bool]: ...
    @property
    def report(self) -> dict[str, Any]: ...
    def evaluate(self, points: ArrayLike) -> npt.NDArray[np.float64]: ...
    def to_json(self) -> str: ...

class Reconstruction:
    """The mesh `stablesurf run` writes, with its report."""

    @property
    def vertices(self) -> npt.NDArray[np.float64]: ...
    @property
    def faces(self) -> npt.NDArray[np.uint32]: ...
    @property
    def normals(self) -> npt.NDArray[np.float64]: ...
    @property
    def report(self) -> dict[str, Any]: ...
    @property
    def watertight(self) -> bool: ...
    @property
    def manifold(self) -> bool: ...
    @property
    def self_intersections(self) -> int: ...
    @property
    def accuracy(self) -> dict[str, Any]: ...
    @property
    def warnings(self) -> list[str]: ...
    @property
    def polynomial(self) -> Optional[Polynomial]: ...

def read_points(path: Union[str, PathLike[str]]) -> Scan: ...
def reconstruct(
    points: Union[ArrayLike, Scan],
    normals: Optional[ArrayLike] = None,
    mode: Literal["detail", "global"] = "detail",
    *,
    faces: Optional[ArrayLike] = None,
    threads: Optional[int] = None,
    depth: int = ...,
    trim: Union[Literal["auto", "off"], float] = ...,
    keep: Literal["data", "all"] = ...,
    degree: int = ...,
    kappa: Union[Literal["auto"], float] = ...,
    kappa_rule: Literal["stable", "paper"] = ...,
    epsilon: float = ...,
    method: Literal["3lrr", "3l", "ls"] = ...,
    local_degree: int = ...,
    tolerance: float = ...,
    smooth: float = ...,
    fit_stride: int = ...,
    normal_source: Literal["auto", "crust", "pca", "mesh", "input"] = ...,
    viewpoint: Sequence[float] = ...,
    keep_outliers: bool = ...,
) -> Reconstruction: ...
def fit(
    points: Union[ArrayLike, Scan],
    normals: Optional[ArrayLike] = None,
    *,
    faces: Optional[ArrayLike] = None,
    degree: Optional[int] = None,
    kappa: Union[Literal["auto"], float, None] = None,
    threads: Optional[int] = None,
    kappa_rule: Literal["stable", "paper"] = ...,
    epsilon: float = ...,
    method: Literal["3lrr", "3l", "ls"] = ...,
    normal_source: Literal["auto", "crust", "pca", "mesh", "input"] = ...,
    viewpoint: Sequence[float] = ...,
    keep_outliers: bool = ...,
) -> Polynomial: ...
