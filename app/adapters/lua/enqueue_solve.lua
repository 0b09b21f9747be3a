-- Queue a solve request (ARGV[1], JSON) on KEYS[1] unless one is pending; reply {created, pending request}.
local head = redis.call('LINDEX', KEYS[1], 0)
if head then
  return {0, head}
end
redis.call('RPUSH', KEYS[1], ARGV[1])
return {1, ARGV[1]}
