"""Type stubs of the vkinverse package."""

from collections.abc import MutableMapping
from os import PathLike
from typing import Any, Callable, Dict, Iterator, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from ._native import Error as Error

Array = npt.NDArray[np.float32]
# fn(image) -> (value, dL/dimage); with several sensors fn(image, sensor).
LossFunction = Union[Callable[[Array], Tuple[float, npt.ArrayLike]], Callable[[Array, int], Tuple[float, npt.ArrayLike]]]

class ParameterError(KeyError, ValueError): ...

def devices() -> List[str]: ...

class Params(MutableMapping[str, Array]):
    def __getitem__(self, name: str) -> Array: ...
    def __setitem__(self, name: str, value: npt.ArrayLike) -> None: ...
    def __delitem__(self, name: str) -> None: ...
    def __iter__(self) -> Iterator[str]: ...
    def __len__(self) -> int: ...
    def shape(self, name: str) -> Tuple[int, ...]: ...
    def range(self, name: str) -> Tuple[float, float]: ...

class Scene:
    params: Params
    def __init__(self, path: Union[str, PathLike[str]], film: Optional[Tuple[int, int]] = None, max_depth: Optional[int] = None, device: Union[None, int, str] = None) -> None: ...
    @property
    def film(self) -> Tuple[int, int]: ...
    @property
    def sensors(self) -> int: ...
    @property
    def warnings(self) -> List[str]: ...
    @property
    def path(self) -> str: ...

def render(scene: Scene, spp: int = 64, seed: int = 0, sensor: int = 0) -> Array: ...
def gradient(scene: Scene, adjoint: npt.ArrayLike, spp: int = 16, seed: int = 0, sensor: int = 0) -> Dict[str, Array]: ...

class HostOptimiser:
    kind: str
    needs_fd: bool
    needs_halves: bool
    skipped: int
    def __init__(self, spec: str, groups: Sequence[Tuple[int, float, float, float]], iterations: Optional[int] = None) -> None: ...
    def __len__(self) -> int: ...
    def step(
        self,
        theta: npt.ArrayLike,
        grad: npt.ArrayLike,
        fd: Optional[npt.ArrayLike] = None,
        grad_half: Optional[npt.ArrayLike] = None,
        fd_half: Optional[npt.ArrayLike] = None,
    ) -> Array: ...
    def diagnostics(self) -> List[Dict[str, float]]: ...

class Result:
    params: Dict[str, Array]
    log: Dict[str, npt.NDArray[Any]]
    interrupted: bool
    out_dir: Optional[Union[str, PathLike[str]]]

def optimise(
    scene: Scene,
    optimiser: str = "meta",
    iterations: Optional[int] = 200,
    loss: Union[str, LossFunction] = "l2",
    targets: Union[None, Array, Sequence[Array]] = None,
    callback: Optional[Callable[[Dict[str, float]], Optional[bool]]] = None,
    out_dir: Optional[Union[str, PathLike[str]]] = None,
    quiet: bool = False,
    resume: bool = False,
    overwrite: bool = False,
    **settings: Any,
) -> Result: ...
