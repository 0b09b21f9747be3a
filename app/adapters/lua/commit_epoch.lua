-- Commit one dispatch epoch atomically (docs/DESIGN.md, "Exactly-once epochs").
-- KEYS[1] meta hash, KEYS[2] epoch record hash, KEYS[3] intervals zset, KEYS[4] open tasks hash,
-- KEYS[5] demand list of the epoch's UTC day, KEYS[6] finished tasks hash, KEYS[7] finished tasks by
-- epoch time (zset), KEYS[8] the open tasks' revision, KEYS[9..] count and visit keys named by index in visits.
-- ARGV[1] JSON {epoch_id, hash, time, expected_version, ttl, done_before, nonce, base_rev, base_tasks_rev,
--               new_rev,
--               visits: [[count_key_index, visit_key_index, interval, [cell, ...]], ...] (one entry per
--                       visit set, its cells distinct),
--               tasks: [[task_id, task_json, '1' if it finishes the task else '0'], ...]};
-- ARGV[2] the response document, ARGV[3] the demand record ('' when nothing is recorded): as they are,
-- not inside ARGV[1] (no 0.5 MB string escaped into JSON and decoded again).
-- A finished task moves from the open hash to the finished ones; finished tasks that finished before
-- done_before (epoch time) are dropped.
-- Cells, intervals, times and the TTL arrive as strings: no number round-trips through a Lua double.
-- c.nonce is unique per commit attempt: finding it on the stored record means this very commit was
-- applied already and its reply lost (the client library sent it again): answer 'committed' again.
-- The state mirror (app/adapters/redis_mirror.py): the commit replaces the meta's rev with new_rev, and the
-- tasks' revision with new_rev when it writes tasks; base_rev and base_tasks_rev are the revisions the
-- caller's mirror holds ('' none, which matches nothing): the reply says whether they were the city's.
-- Returns {'duplicate', hash, time, response} | {'version_mismatch'} | {'stale'} |
-- {'committed', version, rev held '1'/'0', tasks revision held '1'/'0'} ({'committed', version} when the
-- nonce shows this commit applied already).
local meta, epoch, intervals, tasks, demand = KEYS[1], KEYS[2], KEYS[3], KEYS[4], KEYS[5]
local done, done_at, tasks_rev = KEYS[6], KEYS[7], KEYS[8]
local c = cjson.decode(ARGV[1])

local stored = redis.call('HMGET', epoch, 'hash', 'time', 'response', 'nonce')
if stored[1] then
  if c.nonce ~= '' and stored[4] == c.nonce then
    return {'committed', redis.call('HGET', meta, 'version')}
  end
  return {'duplicate', stored[1], stored[2], stored[3]}
end
local m = redis.call('HMGET', meta, 'version', 'last_time', 'rev')
if tonumber(m[1] or '0') ~= tonumber(c.expected_version) then
  return {'version_mismatch'}
end
if m[2] and tonumber(c.time) < tonumber(m[2]) then
  return {'stale'}
end
local rev_held = c.base_rev ~= '' and m[3] == c.base_rev
local tasks_held = c.base_tasks_rev ~= '' and redis.call('GET', tasks_rev) == c.base_tasks_rev

local touched = {}
local seen_intervals = {}
local grown = {}  -- count key index -> {cell -> how many visit sets gained it}
for _, v in ipairs(c.visits) do
  local count_key, visit_key, cells = KEYS[v[1]], KEYS[v[2]], v[4]
  -- a (taxi, interval, cell) is counted at most once ever: Lambda grows only for a new set member
  for i = 1, #cells, 1000 do
    local part = {unpack(cells, i, math.min(i + 999, #cells))}
    local member = redis.call('SMISMEMBER', visit_key, unpack(part))
    redis.call('SADD', visit_key, unpack(part))
    local add = grown[v[1]]
    if not add then
      add = {}
      grown[v[1]] = add
    end
    for j, cell in ipairs(part) do
      if member[j] == 0 then
        add[cell] = (add[cell] or 0) + 1
      end
    end
  end
  seen_intervals[v[3]] = true
  touched[count_key] = true
  touched[visit_key] = true
end
for k, add in pairs(grown) do
  for cell, n in pairs(add) do
    redis.call('HINCRBY', KEYS[k], cell, n)
  end
end
for k, _ in pairs(seen_intervals) do
  redis.call('ZADD', intervals, k, k)
end
for key, _ in pairs(touched) do
  redis.call('EXPIRE', key, c.ttl)
end
for _, t in ipairs(c.tasks) do
  if t[3] == '1' then
    redis.call('HDEL', tasks, t[1])
    redis.call('HSET', done, t[1], t[2])
    redis.call('ZADD', done_at, c.time, t[1])
  else
    redis.call('HSET', tasks, t[1], t[2])
  end
end
local old = redis.call('ZRANGEBYSCORE', done_at, '-inf', '(' .. c.done_before)
for i = 1, #old, 1000 do
  redis.call('HDEL', done, unpack(old, i, math.min(i + 999, #old)))
end
if #old > 0 then
  redis.call('ZREMRANGEBYSCORE', done_at, '-inf', '(' .. c.done_before)
end
redis.call('HSET', epoch, 'hash', c.hash, 'time', c.time, 'response', ARGV[2], 'nonce', c.nonce)
redis.call('EXPIRE', epoch, c.ttl)
if ARGV[3] ~= '' then
  redis.call('RPUSH', demand, ARGV[3])
  redis.call('EXPIRE', demand, c.ttl)
end
if #c.tasks > 0 then
  redis.call('SET', tasks_rev, c.new_rev)
end
local version = redis.call('HINCRBY', meta, 'version', 1)
redis.call('HSET', meta, 'last_time', c.time, 'last_epoch', c.epoch_id, 'rev', c.new_rev)
redis.call('EXPIRE', meta, c.ttl)
return {'committed', version, rev_held and '1' or '0', tasks_held and '1' or '0'}
