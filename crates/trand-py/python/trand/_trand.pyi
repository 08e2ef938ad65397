"""The native module behind ``trand`` (flat little-endian buffers in and out). Use ``trand``'s API."""

from os import PathLike
from typing import Dict, List, Optional, Sequence, Tuple, Union

__version__: str

_View = Tuple[bytes, bytes, int, int, Sequence[float], Sequence[float]]

class NativeScene:
    @property
    def object_ids(self) -> List[int]: ...
    @property
    def state(self) -> str: ...
    @property
    def removed(self) -> List[int]: ...
    @property
    def report(self) -> str: ...
    def __len__(self) -> int: ...
    def points(self, object_id: Optional[int] = None) -> bytes: ...
    @property
    def far(self) -> float: ...
    def render(
        self,
        k: Sequence[float],
        w2c: Sequence[float],
        width: int,
        height: int,
        far: Optional[float] = None,
    ) -> Dict[str, bytes]: ...
    def update(
        self, view: _View, removed: Optional[List[int]], identity: str, progress: bool
    ) -> NativeScene: ...
    def save(self, path: Union[str, PathLike[str]]) -> None: ...

def reconstruct(
    views: List[_View],
    iterations: Optional[int],
    downsample: int,
    seed: int,
    method: str,
    identity: str,
    progress: bool,
) -> NativeScene: ...
def load(path: Union[str, PathLike[str]]) -> NativeScene: ...
def load_sequence(path: Union[str, PathLike[str]], views: Optional[int]) -> Dict[str, object]: ...
def synth(out: Union[str, PathLike[str]], preset: str, seed: int) -> None: ...
