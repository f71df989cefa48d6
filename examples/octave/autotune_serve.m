function autotune_serve(simulate)
% AUTOTUNE_SERVE  Serve autotune's worker protocol (docs/external.md) on stdin/stdout.
%
%   autotune_serve(@simulate) reads one JSON request per line from stdin,
%
%     {"id": 17, "theta": {"q": 0.2, ...}, "seed": 2, "runs": [64, 128],
%      "steps": 200, "dir": "/tmp/autotune-w1-Xy3"}
%
%   calls
%
%     rec = simulate(theta, seed, runs, steps)
%
%   and answers with one line, {"id":17,"file":"/tmp/autotune-w1-Xy3/17.csv"}, after
%   writing the records to that CSV file; or {"id":17,"error":"..."} when simulate (or
%   anything else) raised an error, and then goes on serving. It returns when stdin
%   closes.
%
%   Arguments of simulate:
%     theta  struct with one field per parameter (the problem file's [params] names)
%     seed   the request's seed as a uint64 (exact, also above 2^53). Draw run i's
%            random numbers from (seed, i) alone, e.g. autotune_rng(seed, i) before the
%            run's draws (the seed contract).
%     runs   [a, b]: the half-open range of 0-based run indices a, a+1, ..., b-1
%     steps  the number of steps T
%
%   simulate returns a struct of arrays in the NumPy layout of docs/external.md, the
%   first two dimensions runs x steps (n_r = b - a rows, run a + r - 1 in row r):
%     rec.e        n_r x T x n         estimation error x - xhat (or rec.x and rec.xhat)
%     rec.P        n_r x T x n x n     covariance after the update
%     rec.nu_<s>   n_r x T x m         innovation of sensor <s>, NaN where it did not measure
%     rec.S_<s>    n_r x T x m x m     its covariance (NaN where it did not measure)
%     rec.nees, rec.nis_<s>, ... n_r x T   precomputed forms; *_dof may be a scalar
%     rec.diverged n_r x 1             step at which the run's filter broke down, 0 if not
%   A single sensor may drop its name (nu, S, u, nis, nis_dof).
%
%   Nothing but protocol lines may reach stdout: end every statement in simulate with a
%   semicolon and print diagnostics with fprintf(stderr, ...). (What simulate prints
%   anyway is caught with evalc and moved to stderr.) Run Octave as
%     octave --no-gui --quiet --norc --no-window-system worker.m

  more off;
  out = 1;                                % stdout: protocol lines only
  err = 2;                                % stderr: everything else
  is_octave = exist('OCTAVE_VERSION', 'builtin') ~= 0;
  if is_octave
    page_screen_output(false);
    % Octave saves its command history at exit and, where ~/.local/share does not exist,
    % says "error: ignoring const execution_exception& while preparing to exit".
    history_save(false);
  end
  while true
    line = read_line(is_octave);
    if ~ischar(line)
      break;                              % stdin closed: autotune is done with us
    end
    line = strtrim(line);
    if isempty(line)
      continue;
    end
    id_text = 'null';
    t0 = tic;
    try
      req = jsondecode(line);
      if ~isstruct(req) || ~isfield(req, 'id')
        error('autotune_serve:request', 'the request has no "id"');
      end
      id_text = id_json(req.id);
      [theta, seed, runs, steps, dir] = parse_request(req, line);
      % evalc catches what simulate prints (a missing semicolon, a disp) so that it
      % cannot corrupt the protocol; it goes to stderr instead.
      rec = [];
      printed = evalc('rec = simulate(theta, seed, runs, steps);');
      if ~isempty(printed)
        fprintf(err, 'autotune_serve: simulate printed (moved to stderr):\n%s\n', printed);
      end
      path = fullfile(dir, [id_file(req.id) '.csv']);
      write_records_csv(path, rec, runs, steps);
      reply = sprintf('{"id":%s,"file":%s}', id_text, jsonencode(path));
      fprintf(err, 'autotune_serve: request %s, runs [%d, %d) x %d steps in %.3f s\n', ...
              id_text, runs(1), runs(2), steps, toc(t0));
    catch e
      msg = e.message;
      where = '';
      if ~isempty(e.stack)
        where = sprintf(' (in %s, line %d)', e.stack(1).name, e.stack(1).line);
      end
      fprintf(err, 'autotune_serve: request %s failed: %s%s\n', id_text, msg, where);
      reply = sprintf('{"id":%s,"error":%s}', id_text, jsonencode([msg where]));
    end
    fprintf(out, '%s\n', reply);
    if is_octave
      fflush(stdout);
    end
  end
end

function line = read_line(is_octave)
  % One line from stdin (without its newline), or -1 at end of input.
  if is_octave
    % Not fgetl(stdin): Octave 7's fgetl/fgets return a line only once the next line
    % (or the end of input) has arrived, which would deadlock the protocol (autotune
    % waits for the answer before it sends the next request). fread of one character
    % at a time returns as soon as that character is there.
    buf = blanks(256);
    n = 0;
    while true
      ch = fread(stdin, 1, '*char');
      if isempty(ch)
        if n == 0
          line = -1;
        else
          line = buf(1:n);                % a last line without a newline
        end
        return;
      end
      if ch == char(10)
        line = buf(1:n);
        return;
      end
      n = n + 1;
      if n > numel(buf)
        buf = [buf, blanks(numel(buf))];
      end
      buf(n) = ch;
    end
  else
    % MATLAB has no fread on stdin; input() reads a line of stdin under -batch.
    try
      line = input('', 's');
    catch
      line = -1;
    end
  end
end

function [theta, seed, runs, steps, dir] = parse_request(req, line)
  need = {'theta', 'seed', 'runs', 'steps', 'dir'};
  for k = 1:numel(need)
    if ~isfield(req, need{k})
      error('autotune_serve:request', 'the request has no "%s"', need{k});
    end
  end
  theta = req.theta;
  if isempty(theta)
    theta = struct();
  end
  if ~isstruct(theta)
    error('autotune_serve:request', '"theta" is not an object');
  end
  runs = double(req.runs(:)');
  if numel(runs) ~= 2 || any(runs ~= fix(runs)) || runs(1) < 0 || runs(2) <= runs(1)
    error('autotune_serve:request', '"runs" is not a range [a, b) with 0 <= a < b');
  end
  steps = double(req.steps);
  if ~isscalar(steps) || steps ~= fix(steps) || steps < 1
    error('autotune_serve:request', '"steps" is not a positive integer');
  end
  dir = req.dir;
  if ~ischar(dir)
    error('autotune_serve:request', '"dir" is not a string');
  end
  seed = exact_seed(req.seed, line);
end

function seed = exact_seed(value, line)
  % jsondecode gives the seed as a double, exact only below 2^53; read the digits
  % from the line itself so that every u64 seed is kept as it is.
  if ~isscalar(value) || ~isnumeric(value) || value < 0 || value ~= fix(value)
    error('autotune_serve:request', '"seed" is not a non-negative integer');
  end
  seed = uint64(value);
  tok = regexp(line, '"seed"\s*:\s*(\d+)', 'tokens', 'once');
  if ~isempty(tok) && numel(tok{1}) <= 20
    s = uint64(0);
    digits = tok{1} - '0';
    for d = digits
      s = s * uint64(10) + uint64(d);
    end
    if double(s) == double(value)         % the same number (not a "seed" inside theta)
      seed = s;
    end
  end
end

function t = id_json(id)
  % The request's id as JSON, echoed back unchanged.
  if isnumeric(id) && isscalar(id) && id == fix(id) && abs(id) < 2^53
    t = sprintf('%d', id);
  else
    t = jsonencode(id);
  end
end

function t = id_file(id)
  % The id as a file name.
  if isnumeric(id) && isscalar(id) && id == fix(id)
    t = sprintf('%d', id);
  else
    t = regexprep(char(string_of(id)), '[^A-Za-z0-9_.-]', '_');
  end
end

function s = string_of(id)
  if ischar(id)
    s = id;
  else
    s = jsonencode(id);
  end
end

function write_records_csv(path, rec, runs, steps)
  % The records as CSV (docs/external.md): run, step, then each quantity flattened
  % with 1-based indices, matrices row by row; one row per run and step, run by run.
  if ~isstruct(rec) || ~isscalar(rec)
    error('autotune_serve:records', 'simulate must return a struct of arrays');
  end
  nr = runs(2) - runs(1);
  T = steps;
  names = fieldnames(rec);
  header = {'run', 'step'};
  blocks = {};
  diverged = [];
  for k = 1:numel(names)
    name = names{k};
    A = double(rec.(name));
    if strcmp(name, 'diverged')
      if numel(A) ~= nr
        error('autotune_serve:records', ...
              'rec.diverged has %d elements, expected one per run (%d)', numel(A), nr);
      end
      diverged = A(:);
      continue;
    end
    kind = field_kind(name);
    sz = size(A);
    switch kind
      case 'scalar'
        if numel(A) == 1
          A = repmat(A, nr, T);
        end
        if ~isequal(size(A), [nr, T])
          check_size(name, A, [nr, T], 'runs x steps');
        end
        blocks{end+1} = reshape(A.', nr * T, 1);
        header{end+1} = name;
      case 'vector'
        if ndims(A) > 3 || sz(1) ~= nr || sz(2) ~= T
          check_size(name, A, [nr, T], 'runs x steps x m');
        end
        m = size(A, 3);
        blocks{end+1} = reshape(permute(A, [2 1 3]), nr * T, m);
        for i = 1:m
          header{end+1} = sprintf('%s_%d', name, i);
        end
      case 'matrix'
        m = size(A, 3);
        if ndims(A) > 4 || sz(1) ~= nr || sz(2) ~= T || size(A, 4) ~= m
          check_size(name, A, [nr, T], 'runs x steps x m x m');
        end
        blocks{end+1} = reshape(permute(A, [2 1 4 3]), nr * T, m * m);
        for i = 1:m
          for j = 1:m
            header{end+1} = sprintf('%s_%d_%d', name, i, j);
          end
        end
      otherwise
        error('autotune_serve:records', ...
              'rec.%s is not a record quantity of docs/external.md', name);
    end
  end
  run_col = runs(1) + reshape(repmat(0:nr-1, T, 1), [], 1);
  step_col = repmat((1:T)', nr, 1);
  M = [run_col, step_col, blocks{:}];
  if ~isempty(diverged)
    % A run that broke down at step k: a row with diverged = 1 at k, nothing after.
    if any(diverged < 0 | diverged > T | diverged ~= fix(diverged))
      error('autotune_serve:records', 'rec.diverged must hold steps 1..%d or 0', T);
    end
    d = reshape(repmat(diverged(:)', T, 1), [], 1);
    keep = d == 0 | step_col <= d;
    at = d > 0 & step_col == d;
    M(at, 3:end) = NaN;
    M = [M, double(at)];
    M = M(keep, :);
    header{end+1} = 'diverged';
  end
  fid = fopen(path, 'w');
  if fid < 0
    error('autotune_serve:write', 'cannot write %s', path);
  end
  cleanup = onCleanup(@() fclose_quiet(fid));
  ncol = size(M, 2);
  fprintf(fid, '%s\n', strjoin(header, ','));
  fmt = ['%d,%d', repmat(',%.17g', 1, ncol - 2), '\n'];
  fprintf(fid, fmt, M.');
end

function fclose_quiet(fid)
  try
    fclose(fid);
  catch
  end
end

function check_size(name, A, lead, what)
  sz = size(A);
  if numel(sz) < numel(lead) || any(sz(1:numel(lead)) ~= lead)
    error('autotune_serve:records', 'rec.%s has size %s, expected %s with runs = %d, steps = %d', ...
          name, mat2str(sz), what, lead(1), lead(2));
  end
  error('autotune_serve:records', 'rec.%s has size %s, expected %s', name, mat2str(sz), what);
end

function kind = field_kind(name)
  % Which shape a record quantity has, by its name.
  sensor = '(_[A-Za-z][A-Za-z0-9_]*)?';
  if ~isempty(regexp(name, ['^(nees|nees_dof|nis' sensor '|nis_dof' sensor ')$'], 'once'))
    kind = 'scalar';
  elseif ~isempty(regexp(name, ['^(e|x|xhat|e2p|nu' sensor '|u' sensor ')$'], 'once'))
    kind = 'vector';
  elseif ~isempty(regexp(name, ['^(P|S' sensor ')$'], 'once'))
    kind = 'matrix';
  else
    kind = '';
  end
end
