function autotune_rng(seed, i)
% AUTOTUNE_RNG  Seed randn (and rand) for run i of the experiment with base seed `seed`.
%
%   autotune_rng(seed, i) makes the random numbers drawn next a function of (seed, i)
%   alone, as autotune's seed contract asks (docs/external.md): call it before drawing
%   run i's noise, and draw each run's numbers in a fixed order. seed may be a uint64
%   (as autotune_serve passes it) or a double; i is the 0-based run index.
%
%   Octave: the Mersenne twister is initialised from the three 32-bit words
%   [seed_high, seed_low, i], so distinct (seed, i) give distinct streams.

  seed = uint64(seed);
  words = [double(bitshift(seed, -32)), double(bitand(seed, uint64(4294967295))), double(i)];
  if exist('OCTAVE_VERSION', 'builtin') ~= 0
    randn('state', words);
    rand('state', words);
  else
    % MATLAB: one 32-bit seed for the Mersenne twister, mixed from the three words.
    h = uint64(2166136261);
    for w = words
      h = mod(bitxor(h, uint64(mod(w, 4294967296))) * uint64(16777619), uint64(4294967296));
    end
    rng(double(h), 'twister');
  end
end
