"""The Moonshine model's text tokens: a SentencePiece-style BPE vocabulary read from the model's
`tokenizer.bin` (one entry per token id: a length byte, then that many UTF-8 bytes).

Only what the constrained search needs: the token ids of a known sentence (`encode`, so each spoken
form can be scored the way the model would write it) and text back from ids (`decode`, for logs).
Merges follow SentencePiece BPE: the adjacent pair whose merged piece has the lowest id is merged
first; a character the vocabulary lacks falls back to its UTF-8 byte tokens.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

SPACE = "\u2581"  # SentencePiece's word-start marker
UNKNOWN, START, END = 0, 1, 2
FIRST_BYTE = 3  # ids 3..258 are the 256 raw bytes
FIRST_PIECE = FIRST_BYTE + 256


class Tokenizer:
    def __init__(self, tokens: Sequence[bytes]) -> None:
        if len(tokens) <= FIRST_PIECE:
            raise ValueError(f"a tokenizer needs more than {FIRST_PIECE} tokens, got {len(tokens)}")
        self._tokens = list(tokens)
        self._pieces: dict[str, int] = {}
        for index in range(FIRST_PIECE, len(tokens)):
            # First id wins: lower ids are earlier (preferred) merges.
            self._pieces.setdefault(tokens[index].decode("utf-8", "replace"), index)

    @classmethod
    def from_file(cls, path: Path) -> Tokenizer:
        data = path.read_bytes()
        tokens: list[bytes] = []
        offset = 0
        while offset < len(data):
            length = data[offset]
            end = offset + 1 + length
            if end > len(data):
                raise ValueError(f"{path}: truncated at token {len(tokens)}")
            tokens.append(data[offset + 1 : end])
            offset = end
        return cls(tokens)

    def __len__(self) -> int:
        return len(self._tokens)

    def piece(self, text: str) -> int | None:
        """The id of a whole piece ("." -> its id), or None."""
        return self._pieces.get(text)

    def encode(self, text: str) -> list[int]:
        """Token ids of one sentence (a leading word-start marker, spaces as markers)."""
        symbols = list(SPACE + text.replace(" ", SPACE))
        while len(symbols) > 1:
            best: tuple[int, int] | None = None
            for position in range(len(symbols) - 1):
                merged = self._pieces.get(symbols[position] + symbols[position + 1])
                if merged is not None and (best is None or merged < best[0]):
                    best = (merged, position)
            if best is None:
                break
            position = best[1]
            symbols[position : position + 2] = [symbols[position] + symbols[position + 1]]
        ids: list[int] = []
        for symbol in symbols:
            known = self._pieces.get(symbol)
            ids += [known] if known is not None else [FIRST_BYTE + byte for byte in symbol.encode()]
        return ids

    def decode(self, ids: Sequence[int]) -> str:
        raw = b"".join(self._tokens[i] for i in ids if FIRST_BYTE <= i < len(self._tokens))
        return raw.decode("utf-8", "replace").replace(SPACE, " ").strip()
